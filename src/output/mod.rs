//! Outputs: tile sinks that stream a PNG or hit data while tiles are still tracing.

pub mod hits;
pub mod png;
pub mod rows;

pub use hits::{HitFormat, HitSink, PixelHit};
pub use png::PngSink;
pub use rows::RowAssembler;
