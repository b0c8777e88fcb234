//! Sinks that stream a PNG or hit data while tiles are still tracing: they put tiles,
//! which finish in any order on any thread, into the order a format needs
//! ([`RowAssembler`]) and hand the rows to the writers of [`crate::format`], a tile to
//! whichever worker is writing ([`handoff`]); and the file they are written to
//! ([`OutputFile`]).

pub mod file;
pub mod footprint;
pub mod frame;
pub mod handoff;
pub mod hits;
pub mod png;
pub mod rows;

pub use file::OutputFile;
pub use footprint::footprint;
pub use frame::FrameSink;
pub use hits::HitSink;
pub use png::PngSink;
pub use rows::RowAssembler;
