//! The file formats, one file each, its reader beside its writer:
//!
//! | file | format | written by | read by |
//! | --- | --- | --- | --- |
//! | [`json`] | hit data, one document (`.json`, `application/json`) | `raytile hits`, `/v1/hits` | the grader |
//! | [`ndjson`] | hit data, one line per tile (`.ndjson`, `application/x-ndjson`) | `raytile hits`, `/v1/hits` | the grader |
//! | [`npy`] | hit data, a NumPy structured array (`.npy`, `application/x-npy`) | `raytile hits`, `/v1/hits` | the grader |
//! | [`csv`] | hit data, a table with a header (`.csv`, `text/csv`) | `raytile hits`, `/v1/hits` | the grader |
//! | [`png`] | 8-bit RGB images (`.png`, `image/png`) | renders, difference images | the grader, `render --servers` |
//! | [`raster`] | every submitted image, told by content: PNG, PPM/PGM/PBM/PAM, BMP, TGA, JPEG (into 8-bit RGB), PFM, OpenEXR (linear) | — | the grader |
//! | [`pfm`] | linear float images (`.pfm`) | `render -o x.pfm` | the grader (via [`raster`]) |
//! | [`exr`] | linear float images (`.exr`, `image/x-exr`) | `render -o x.exr` | the grader (via [`raster`]) |
//! | [`linear`] | the linear frame in memory ([`LinearImage`]) | the renderer's [`crate::render::LinearKernel`] | — |
//!
//! What the hit-data formats share lives in [`hit`]: the record a pixel is written as
//! ([`PixelHit`]), the record it is read back as ([`SubmittedHit`]), and [`HitFormat`]
//! with each format's name, extension and media type, so those strings are spelt once.
//!
//! A format here only turns records into bytes and bytes into records. Streaming, the
//! part that copes with tiles finishing in any order on many threads, stays in
//! [`crate::output`]: its sinks put rows in order ([`crate::output::RowAssembler`]) and
//! call the writers here for each header, row or tile. Kept apart, each format is a
//! handful of plain functions that a round-trip test (write, then read) pins, and the
//! sinks are one piece of concurrency shared by all of them.
//!
//! Readers trust nothing: every problem is a [`ReadError`] saying where. The layers:
//! `format` uses `geometry` (surfaces), `scene` (object names) and `render` (rectangles);
//! `output`, `grade`, `server` and `cli` use `format`, never the other way.
//!
//! [`json`]: crate::format::json
//! [`ndjson`]: crate::format::ndjson
//! [`npy`]: crate::format::npy
//! [`csv`]: crate::format::csv
//! [`png`]: crate::format::png
//! [`raster`]: crate::format::raster
//! [`pfm`]: crate::format::pfm
//! [`exr`]: crate::format::exr
//! [`linear`]: crate::format::linear
//! [`LinearImage`]: crate::format::LinearImage
//! [`hit`]: crate::format::hit
//! [`PixelHit`]: crate::format::PixelHit
//! [`SubmittedHit`]: crate::format::SubmittedHit
//! [`HitFormat`]: crate::format::HitFormat
//! [`ReadError`]: crate::format::ReadError

pub mod csv;
pub mod exr;
pub mod footprint;
pub mod hit;
pub mod json;
pub mod linear;
pub mod ndjson;
pub mod npy;
pub mod pfm;
pub mod png;
pub mod raster;

pub use self::png::RgbImage;
pub use hit::{Group, HitData, HitFormat, PixelHit, SubmittedHit};
pub use linear::LinearImage;
pub use raster::{DecodeLimits, Raster, RasterFormat};

/// Why bytes could not be read as a format. [`crate::grade::GradeError`] carries it as
/// `Unreadable`, saying in its own words only what makes a submission the wrong thing
/// (not a PNG, not the scene's size).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReadError {
    /// A PNG was expected but the bytes are not one.
    #[error("it is not a PNG file (it does not start with the PNG signature)")]
    NotPng,
    /// A PNG that cannot be decoded.
    #[error("the PNG file is corrupt: {0}")]
    CorruptPng(String),
    /// An image of another format (PPM, BMP, TGA, JPEG, PFM, OpenEXR) that cannot be
    /// decoded.
    #[error("the {format} file is corrupt: {message}")]
    CorruptImage {
        /// `"PPM"`, `"BMP"`, `"TGA"`, `"JPEG"`, `"PFM"` or `"OpenEXR"`.
        format: &'static str,
        /// The decoder's words.
        message: String,
    },
    /// An image whose decoding would take more memory than allowed (told from its
    /// header).
    #[error("the {format} image is too large: decoding it would need more than {} MiB", .limit_bytes >> 20)]
    TooLarge {
        /// The format's title.
        format: &'static str,
        /// The allowance.
        limit_bytes: usize,
    },
    /// An image with a pixel that is not opaque.
    #[error(
        "pixel ({u}, {v}) is not opaque (alpha {alpha}): the grader compares colours and cannot tell what a transparent pixel should show; save the image without alpha, or with every pixel opaque"
    )]
    NotOpaque {
        /// Column.
        u: u32,
        /// Row.
        v: u32,
        /// Its alpha, as stored.
        alpha: String,
    },
    /// An image that is not the size asked for (told from its header).
    #[error("the image is {width} × {height} pixels, not {expected_width} × {expected_height}")]
    SizeMismatch {
        /// Its width.
        width: u32,
        /// Its height.
        height: u32,
        /// The width asked for.
        expected_width: u32,
        /// The height asked for.
        expected_height: u32,
    },
    /// JSON, NDJSON or CSV that does not parse (or has the wrong types).
    #[error("the hit data is not valid {format}: {message} (line {line}, column {column})")]
    Syntax {
        /// `"JSON"`, `"NDJSON"` or `"CSV"`.
        format: &'static str,
        /// 1-based line.
        line: usize,
        /// 1-based column (0 when unknown).
        column: usize,
        /// What is wrong.
        message: String,
    },
    /// Hit data whose layout is not an `(h, w)` grid of hit records.
    #[error("the hit data has the wrong shape: {0}")]
    WrongShape(String),
    /// A required column or field is absent.
    #[error("the hit data has no {what} `{field}` (needed: {needed})")]
    MissingField {
        /// `"CSV column"` or `"NPY field"`.
        what: &'static str,
        /// The missing name.
        field: String,
        /// What the format needs.
        needed: &'static str,
    },
    /// A value that is not what its field needs.
    #[error("{at}: {message}")]
    BadValue {
        /// Where: a JSON path, a CSV line and column.
        at: String,
        /// What is wrong.
        message: String,
    },
    /// A malformed `.npy` file.
    #[error("the NPY file is malformed: {0}")]
    Npy(String),
}

impl ReadError {
    /// A stable, machine-readable name for the kind of problem (the `reason` member of
    /// an invalid-submission problem document).
    pub fn reason(&self) -> &'static str {
        match self {
            ReadError::NotPng => "not-png",
            ReadError::CorruptPng(_) => "corrupt-png",
            ReadError::CorruptImage { .. } => "corrupt-image",
            ReadError::TooLarge { .. } => "too-large",
            ReadError::NotOpaque { .. } => "not-opaque",
            ReadError::SizeMismatch { .. } => "size-mismatch",
            ReadError::Syntax { .. } => "syntax",
            ReadError::WrongShape(_) => "wrong-shape",
            ReadError::MissingField { .. } => "missing-field",
            ReadError::BadValue { .. } => "bad-value",
            ReadError::Npy(_) => "npy",
        }
    }
}
