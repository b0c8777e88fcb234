//! The integration tests, one binary. Modules:
//! - `support`: helpers (the built binary, scene files, temporary outputs);
//! - `support_server`: a `TestApp` (the real router on a loopback port), scene makers;
//! - `assignment`: `raytile grade-assignment`, a whole assignment graded offline, hidden
//!   scenes' feedback redacted;
//! - `assignments_http`: the assignment routes of `raytile serve`: pushing, reading,
//!   grader scoping, submissions (hidden feedback, idempotency, the rate limit), on
//!   SQLite and PostgreSQL (PostgreSQL's run is ignored unless asked for);
//! - `auth`: `raytile token create` and `serve --require-token`: bearer tokens and
//!   roles on SQLite and PostgreSQL (PostgreSQL's run is ignored unless asked for:
//!   `bash .ci/test-all` starts one);
//! - `cli`: `raytile render | hits | validate` as a user runs them;
//! - `cost`: the ray budget, its refusals and its cut renders;
//! - `diagnose`: naming the mistake behind a failing submission, each mistake made by
//!   `wrong_tracer` (a student's tracer written from the specification, with a flag per
//!   mistake) or by moving the reference's pixels;
//! - `formats`: every submission format, from files written by other encoders
//!   (`tests/fixtures/submissions/`), by `raytile grade` and `POST /v1/grade`;
//! - `cluster`: two `raytile serve` processes behind nginx, and `render --servers`
//!   finishing a frame while a replica dies (the nginx test is ignored unless asked for:
//!   `bash .ci/test-all` installs nginx and runs it);
//! - `grade`: `raytile trace | grade` as an instructor runs them;
//! - `gradebook`: an assignment's submissions, `grades.csv` and statistics for
//!   instructors only, and `raytile assignment push | grades`, on SQLite and PostgreSQL
//!   (PostgreSQL's run is ignored unless asked for);
//! - `geometry`: shapes under transforms against hand-computed answers;
//! - `imports`: no two modules import each other, the server never the command line;
//! - `lecture`: the lecture's worked example;
//! - `lms`: Gradescope's and PrairieLearn's results files (ungradable submissions,
//!   folders, visibility) and the scoring modes, on the command line and over HTTP;
//! - `memory`: the memory budget, its refusals, its queue and its ledger;
//! - `properties`: BVH against brute force, invariance, determinism, regions;
//! - `reference_cache`: references rendered once over `/v1/grade`, the same answers;
//! - `schema`: the JSON Schema and the parser agree;
//! - `openapi`: `api/openapi.yaml` and the server agree;
//! - `server`: the HTTP service as a client sees it, and the binary's `serve` and
//!   `healthcheck`;
//! - `streaming`: streamed answers of any shape in small chunks, and clients that do
//!   not read (parked renders, resumed or stopped);
//! - `server_grade`: `POST /v1/trace` and `POST /v1/grade` as an instructor's scripts
//!   use them;
//! - `submit`: `raytile submit` and `raytile scenes` as a grader's container runs them:
//!   a results file whatever happens, retries with one idempotency key, and whole
//!   submissions recorded once against a real server, also through a SIGKILL;
//! - `studio`: the web page at `GET /` in a real browser (ignored unless asked for:
//!   `bash .ci/test-all` installs chromium and the page's npm packages and runs it);
//! - `validation`: every class of bad document, with its pointer.

mod support;
mod support_server;

mod assignment;
mod assignments_http;
mod auth;
mod cli;
mod cluster;
mod cost;
mod diagnose;
mod formats;
mod geometry;
mod grade;
mod gradebook;
mod imports;
mod lecture;
mod lms;
mod memory;
mod openapi;
mod properties;
mod reference_cache;
mod schema;
mod server;
mod server_grade;
mod streaming;
mod studio;
mod submit;
mod validation;
mod wrong_tracer;
