//! raytile: a ray tracer that follows the COSC342 lecture's mathematics to the last digit,
//! split into tiles traced on all cores, with outputs that stream.
#![forbid(unsafe_code)]

pub mod cli;
pub mod geometry;
pub mod grade;
pub mod output;
pub mod render;
pub mod scene;
