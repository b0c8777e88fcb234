//! The integration tests, one binary. Modules:
//! - `support`: helpers (the built binary, scene files, temporary outputs);
//! - `cli`: `raytile render | hits | validate` as a user runs them;
//! - `grade`: `raytile trace | grade` as an instructor runs them;
//! - `geometry`: shapes under transforms against hand-computed answers;
//! - `lecture`: the lecture's worked example;
//! - `properties`: BVH against brute force, invariance, determinism, regions;
//! - `schema`: the JSON Schema and the parser agree;
//! - `validation`: every class of bad document, with its pointer.

mod support;

mod cli;
mod geometry;
mod grade;
mod lecture;
mod properties;
mod schema;
mod validation;
