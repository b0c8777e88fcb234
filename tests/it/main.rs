//! The integration tests, one binary. Modules:
//! - `support`: helpers (the built binary, scene files, temporary outputs);
//! - `support_server`: a `TestApp` (the real router on a loopback port), scene makers;
//! - `cli`: `raytile render | hits | validate` as a user runs them;
//! - `server`: the HTTP service as a client sees it, and the binary's `serve` and
//!   `healthcheck`;
//! - `openapi`: `api/openapi.yaml` and the server agree.

mod support;
mod support_server;

mod cli;
mod openapi;
mod server;
