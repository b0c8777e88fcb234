//! The command line: `render`, `hits` and `validate` a scene file, and the server
//! commands `serve` (the default) and `healthcheck`. The subcommands live in their own
//! files; `main.rs` only calls [`run`]. `render --servers` (in `distributed`) renders
//! one frame across several servers.
//!
//! [`run`]: crate::cli::run

mod assignment;
mod assignment_remote;
pub mod distributed;
mod grade;
mod input;
mod local;
pub mod remote;
mod scenes;
mod serve;
mod submit;
mod token;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

use crate::render::{OutsideFrame, Rect, region_in_frame};
use crate::scene::Scene;

/// raytile: ray trace JSON scenes, from the command line or as an HTTP service.
#[derive(Debug, Parser)]
#[command(name = "raytile", version, about, long_about = None)]
pub struct Cli {
    /// What to do; without a command, `serve`.
    #[command(subcommand)]
    pub command: Option<Command>,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Render a scene to a PNG, here or across servers (`--servers`).
    Render(local::RenderArgs),
    /// Write per-pixel hit data (JSON, NDJSON, NPY or CSV, by the output's extension).
    Hits(local::HitsArgs),
    /// Check a scene and list every problem with its JSON pointer.
    Validate(local::ValidateArgs),
    /// Explain one pixel: its ray tree with every intermediate value of the lecture.
    Trace(grade::TraceArgs),
    /// Grade a submission (a PNG or hit data) against the scene's reference.
    Grade(grade::GradeArgs),
    /// Grade a whole assignment offline: each file of DIR for the scene its stem names.
    GradeAssignment(assignment::GradeAssignmentArgs),
    /// Push an assignment to a course server, or download its gradebook.
    Assignment(assignment_remote::AssignmentArgs),
    /// Serve the HTTP API (the default when no command is given).
    Serve(crate::config::ServeArgs),
    /// Probe a running server's `/healthz`: exit 0 when it answers 200, 1 otherwise.
    Healthcheck(serve::HealthcheckArgs),
    /// Create or revoke the bearer tokens that `--require-token` asks for.
    Token(token::TokenArgs),
    /// Grade files on the grading service and write the results file (a grader's
    /// container runs it; a results file is written even when the service is down).
    Submit(submit::SubmitArgs),
    /// Fetch an assignment's scene documents from the grading service into a folder.
    Scenes(scenes::ScenesArgs),
}

/// Options shared by the commands that trace.
#[derive(Debug, Clone, clap::Args)]
pub struct TraceOptions {
    /// The scene file (JSON); `-` reads standard input.
    pub scene: PathBuf,
    /// Rayon worker threads (default: one per core).
    #[arg(long, env = "RAYTILE_THREADS")]
    pub threads: Option<usize>,
    /// Tile edge in pixels.
    #[arg(long, default_value_t = crate::render::DEFAULT_TILE_PX, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub tile: u32,
    /// Only this rectangle of the frame: `x,y,w,h` in pixels.
    #[arg(long)]
    pub region: Option<Rect>,
    /// Print one JSON line of phase timings to standard error.
    #[arg(long)]
    pub stats: bool,
}

impl TraceOptions {
    /// `--region` within the scene's frame, or the whole frame without one.
    fn region_in(&self, scene: &Scene) -> Result<Rect, OutsideFrame> {
        region_in_frame(self.region, scene.width, scene.height)
    }
}

/// Runs the command line; the exit code on success.
pub fn run(cli: Cli) -> anyhow::Result<std::process::ExitCode> {
    match cli.command {
        Some(Command::Render(a)) => local::render(a),
        Some(Command::Hits(a)) => local::hits(a),
        Some(Command::Validate(a)) => local::validate(a),
        Some(Command::Trace(a)) => grade::trace(a),
        Some(Command::Grade(a)) => grade::grade(a),
        Some(Command::GradeAssignment(a)) => assignment::grade_assignment(a),
        Some(Command::Assignment(a)) => assignment_remote::assignment(a),
        Some(Command::Serve(a)) => serve::serve(a),
        Some(Command::Healthcheck(a)) => serve::healthcheck(a),
        Some(Command::Token(a)) => token::token(a),
        Some(Command::Submit(a)) => submit::submit(a),
        Some(Command::Scenes(a)) => scenes::scenes(a),
        // No command: serve, configured by the environment alone.
        None => serve::serve(crate::config::ServeArgs::from_env().map_err(|e| e.exit())?),
    }
}
