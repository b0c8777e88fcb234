//! The file a command writes its output to: an existing file is overwritten in place,
//! its first page last.
//!
//! Opening with truncation frees every page the old file had in memory, and writing
//! then allocates and fills fresh ones: for the 79 MB of a 1024 × 768 NPY, writing over
//! the same file again took about four times as long as writing into the pages it
//! already had. So an existing regular file is not truncated: its bytes are replaced
//! where they stand, and it is cut to the new length at the end ([`OutputFile::commit`]).
//!
//! What a run that stops half-way leaves must never read as a whole file (new rows
//! above, the old file's rows below). So the first [`HEAD`] bytes are held back: on
//! opening, the old file's first page is zeroed; the new first page is written only
//! once everything else is. Until then the file starts with zeros, which no format
//! written here (NPY, PNG, JSON, CSV, NDJSON, EXR, PFM) accepts as its start.
//!
//! Anything that is not a regular file (a terminal, `/dev/null`, a pipe) is written
//! straight through.

use std::fs::{File, OpenOptions};
use std::io::{self, Seek, SeekFrom, Write};
use std::path::Path;
use std::sync::{Arc, Mutex, MutexGuard};

/// Bytes written last: a page.
pub const HEAD: usize = 4096;

/// A file being written; clones write to the same file. Call [`OutputFile::commit`]
/// once everything is written.
#[derive(Clone)]
pub struct OutputFile(Arc<Mutex<Target>>);

struct Target {
    file: File,
    /// The first bytes written, up to [`HEAD`], while they are held back; `None` for a
    /// file that is written straight through. Everything after them is written at
    /// `HEAD` on, so the file's position says how long it is once they are whole.
    head: Option<Vec<u8>>,
}

impl OutputFile {
    /// Opens `path` for writing, creating it if it does not exist (as `File::create`
    /// does, without truncating it).
    pub fn create(path: &Path) -> io::Result<OutputFile> {
        let mut file = OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)?;
        let meta = file.metadata()?;
        let head = if meta.is_file() {
            let old = meta.len();
            file.write_all(&[0u8; HEAD][..old.min(HEAD as u64) as usize])?;
            file.seek(SeekFrom::Start(HEAD as u64))?;
            Some(Vec::with_capacity(HEAD))
        } else {
            None
        };
        Ok(OutputFile(Arc::new(Mutex::new(Target { file, head }))))
    }

    fn target(&self) -> io::Result<MutexGuard<'_, Target>> {
        self.0
            .lock()
            .map_err(|_| io::Error::other("a writer panicked"))
    }

    /// Completes the file: cuts what is left of an older, longer file, then writes the
    /// first page.
    pub fn commit(&self) -> io::Result<()> {
        let mut t = self.target()?;
        let Target { file, head } = &mut *t;
        if let Some(head) = head.take() {
            let len = if head.len() < HEAD {
                head.len() as u64
            } else {
                file.stream_position()?
            };
            file.set_len(len)?;
            file.seek(SeekFrom::Start(0))?;
            file.write_all(&head)?;
        }
        file.flush()
    }
}

/// Holds back what of `buf` the first page still has room for; the bytes taken.
fn hold(head: &mut Vec<u8>, buf: &[u8]) -> usize {
    let n = (HEAD - head.len()).min(buf.len());
    head.extend_from_slice(&buf[..n]);
    n
}

impl Write for OutputFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let mut t = self.target()?;
        let Target { file, head } = &mut *t;
        match head {
            Some(head) if head.len() < HEAD => Ok(hold(head, buf)),
            _ => file.write(buf),
        }
    }

    /// While the first page is held back, the first buffer with bytes (as `write`
    /// takes it); then every buffer in one call.
    fn write_vectored(&mut self, bufs: &[io::IoSlice<'_>]) -> io::Result<usize> {
        let mut t = self.target()?;
        let Target { file, head } = &mut *t;
        match head {
            Some(head) if head.len() < HEAD => {
                let first = bufs.iter().find(|b| !b.is_empty());
                Ok(first.map_or(0, |buf| hold(head, buf)))
            }
            _ => file.write_vectored(bufs),
        }
    }

    fn flush(&mut self) -> io::Result<()> {
        self.target()?.file.flush()
    }
}

/// Writes every byte of `bufs`, in order, in as few calls as `out` takes them
/// (`Write::write_all_vectored` is not stable): a writer that takes one buffer a call,
/// as `Write`'s default does, still gets them all.
pub fn write_all_vectored<W: Write + ?Sized>(
    out: &mut W,
    mut bufs: &mut [io::IoSlice<'_>],
) -> io::Result<()> {
    // Leading empty buffers dropped, so that a call never writes nothing.
    io::IoSlice::advance_slices(&mut bufs, 0);
    while !bufs.is_empty() {
        match out.write_vectored(bufs) {
            Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
            Ok(n) => io::IoSlice::advance_slices(&mut bufs, n),
            Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bytes(n: usize, seed: u8) -> Vec<u8> {
        (0..n)
            .map(|i| (i as u8).wrapping_mul(31).wrapping_add(seed))
            .collect()
    }

    fn write_in_pieces(out: &mut OutputFile, data: &[u8]) {
        for piece in data.chunks(1000) {
            out.write_all(piece).unwrap();
        }
    }

    #[test]
    fn an_existing_file_holds_exactly_the_new_bytes_whatever_their_lengths() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        // Longer and shorter than the old file, and than the held-back head.
        for (k, n) in [50_000, 90_000, 20_000, 3000, 0, HEAD, HEAD + 1, 10]
            .into_iter()
            .enumerate()
        {
            let data = bytes(n, k as u8);
            let mut out = OutputFile::create(&path).unwrap();
            write_in_pieces(&mut out, &data);
            out.commit().unwrap();
            drop(out);
            assert!(
                std::fs::read(&path).unwrap() == data,
                "{n} bytes over the last"
            );
        }
    }

    #[test]
    fn vectored_writes_give_the_bytes_single_writes_give() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        // Pieces of every size about the held-back head: each call may end inside
        // the head, across its end or beyond it.
        for (k, n) in [50_000, 20_000, HEAD, HEAD + 1, 10, 0]
            .into_iter()
            .enumerate()
        {
            let data = bytes(n, k as u8);
            let mut pieces = Vec::new();
            let mut rest = &data[..];
            for size in [700, 1, 0, 5000, 3000].into_iter().cycle() {
                if rest.is_empty() {
                    break;
                }
                let (piece, after) = rest.split_at(size.min(rest.len()));
                pieces.push(io::IoSlice::new(piece));
                rest = after;
            }
            let mut out = OutputFile::create(&path).unwrap();
            for group in pieces.chunks_mut(7) {
                write_all_vectored(&mut out, group).unwrap();
            }
            out.commit().unwrap();
            drop(out);
            assert!(std::fs::read(&path).unwrap() == data, "{n} bytes");
        }
    }

    /// Takes at most `most` bytes a call, of the first buffer only (`Write`'s
    /// default `write_vectored`), or none at all.
    struct Trickle {
        got: Vec<u8>,
        most: usize,
    }

    impl Write for Trickle {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            let n = buf.len().min(self.most);
            self.got.extend_from_slice(&buf[..n]);
            Ok(n)
        }

        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn every_byte_is_written_by_a_writer_that_takes_a_little_at_a_time() {
        let data = bytes(10_000, 4);
        let mut pieces: Vec<io::IoSlice<'_>> = data.chunks(333).map(io::IoSlice::new).collect();
        let mut out = Trickle {
            got: Vec::new(),
            most: 100,
        };
        write_all_vectored(&mut out, &mut pieces).unwrap();
        assert!(out.got == data);
        // A writer that takes nothing is an error, not a loop.
        let mut stuck = Trickle {
            got: Vec::new(),
            most: 0,
        };
        let mut pieces = [io::IoSlice::new(&data)];
        let e = write_all_vectored(&mut stuck, &mut pieces).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::WriteZero);
    }

    #[test]
    fn a_write_that_stops_before_commit_leaves_no_readable_start() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        std::fs::write(&path, bytes(60_000, 1)).unwrap();
        let mut out = OutputFile::create(&path).unwrap();
        let new = bytes(40_000, 2);
        write_in_pieces(&mut out, &new[..30_000]);
        drop(out);
        let left = std::fs::read(&path).unwrap();
        assert!(
            left[..HEAD].iter().all(|&b| b == 0),
            "the old start is left"
        );
        // Past the head, what was written is where it belongs.
        assert!(left[HEAD..30_000] == new[HEAD..30_000]);

        // A file that did not exist starts with a hole, which reads as zeros.
        let fresh = dir.path().join("fresh.bin");
        let mut out = OutputFile::create(&fresh).unwrap();
        write_in_pieces(&mut out, &new);
        drop(out);
        let left = std::fs::read(&fresh).unwrap();
        assert!(left[..HEAD].iter().all(|&b| b == 0));
        assert!(left[HEAD..] == new[HEAD..]);
    }

    #[test]
    fn a_pipe_is_written_through_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("pipe");
        let made = std::process::Command::new("mkfifo")
            .arg(&path)
            .status()
            .unwrap();
        assert!(made.success());
        let reader = {
            let path = path.clone();
            std::thread::spawn(move || std::fs::read(path).unwrap())
        };
        // A pipe can neither seek nor be written at an offset: holding the head back
        // would fail here.
        let data = bytes(3 * HEAD, 3);
        let mut out = OutputFile::create(&path).unwrap();
        write_in_pieces(&mut out, &data);
        out.commit().unwrap();
        drop(out);
        assert!(reader.join().unwrap() == data);
    }

    #[test]
    fn clones_write_one_file_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.bin");
        let data = bytes(9000, 4);
        let out = OutputFile::create(&path).unwrap();
        let (mut a, mut b) = (out.clone(), out.clone());
        a.write_all(&data[..5000]).unwrap();
        b.write_all(&data[5000..]).unwrap();
        out.commit().unwrap();
        assert!(std::fs::read(&path).unwrap() == data);
    }
}
