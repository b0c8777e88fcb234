//! raytile: a ray tracer that follows the COSC342 lecture's mathematics to the last digit,
//! split into tiles traced on all cores, with outputs that stream.
// Denied, not forbidden: the AVX2 box test (`geometry::bounds::avx2`) must call code
// compiled for a processor feature found at run time, which only `unsafe` can.
#![deny(unsafe_code)]

/// Assignments: several scenes graded together, with visibility per scene.
pub mod assignment;
/// The command line: render, hits, validate, serve, healthcheck.
pub mod cli;
/// The server's configuration (flags and environment).
pub mod config;
/// The file formats, reader beside writer: hit data (JSON, NDJSON, NPY, CSV) and PNG.
pub mod format;
/// Rays, transforms, shapes, the BVH and hit records.
pub mod geometry;
/// Autograding: explain a pixel, grade a submission against the reference.
pub mod grade;
/// Reading JSON strictly, the failing field's path and the position apart.
pub mod json;
/// The unit tests' counting allocator, for the memory estimators' tests.
#[cfg(test)]
mod measure;
/// Sinks that stream PNG and hit data while tiles trace.
pub mod output;
/// The camera, Whitted shading and the tile loop.
pub mod render;
/// The scene document and its validation.
pub mod scene;
/// The HTTP service on axum and tokio.
pub mod server;
/// The database: tokens, assignments, submissions (SQLite or PostgreSQL).
pub mod store;
