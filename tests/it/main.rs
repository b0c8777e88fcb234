//! The integration tests, one binary. Modules:
//! - `support`: helpers (the built binary, scene files, temporary outputs);
//! - `cli`: `raytile render | hits | validate` as a user runs them;
//! - `grade`: `raytile trace | grade` as an instructor runs them.

mod support;

mod cli;
mod grade;
