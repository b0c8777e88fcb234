//! The server's configuration: one clap struct, every setting a flag with a matching
//! environment variable (`--max-renders` / `RAYTILE_MAX_RENDERS`), so the same binary is
//! configured by hand on a laptop and by the environment in a container.
//!
//! Defaults are for one replica on one machine: a render slot per core, a short queue, a
//! generous deadline, and the scene limits of [`crate::scene::Limits::default`].

use std::net::SocketAddr;
use std::time::Duration;

use crate::render::DEFAULT_TILE_PX;
pub use crate::render::cost::DEFAULT_MAX_RAYS;
use crate::scene::{DEEPEST, Limits};

/// Where the server listens unless told otherwise.
pub const DEFAULT_ADDR: &str = "0.0.0.0:8080";
/// The largest request body: 16 MiB (a scene with large inline meshes).
pub const DEFAULT_MAX_BODY_BYTES: usize = 16 * 1024 * 1024;
/// Requests that may wait for a render slot before the next one is refused.
pub const DEFAULT_QUEUE: usize = 16;
/// How long a request may take, from its first byte in to its last byte out.
pub const DEFAULT_DEADLINE_SECONDS: f64 = 300.0;
/// How long in-flight responses may run on after SIGTERM.
pub const DEFAULT_GRACE_SECONDS: f64 = 25.0;
/// How long a response may wait for a client that takes nothing.
pub const DEFAULT_STALL_SECONDS: f64 = 15.0;
/// The memory budget requests are charged against (`server::memory`): 768 MiB, for the
/// 1 GiB container limit in `deploy/`. The headroom rule: the budget is the container's
/// limit less what the process holds before any request (the binary, its thread stacks,
/// the allocator's slack; an idle release server's VmHWM is about 9 MiB) and a
/// margin for what no estimate sees (hyper's buffers of open connections, the
/// allocator's fragmentation under load): a quarter of the limit.
pub const DEFAULT_MEMORY_BYTES: u64 = 768 * 1024 * 1024;
/// The largest memory budget: what the ledger counts, in KiB with `u32` (4 TiB).
pub const MAX_MEMORY_BYTES: u64 = u32::MAX as u64 * 1024;
/// Memory a budget keeps beyond two bodies of `--max-body-bytes` at least.
pub const MIN_MEMORY_HEADROOM_BYTES: u64 = 16 * 1024 * 1024;
/// Connections open at once: well under the usual limit of 1024 file descriptors.
pub const DEFAULT_MAX_CONNECTIONS: u32 = 512;
/// How long a request's head may take to arrive, from its first byte.
pub const DEFAULT_HEADER_TIMEOUT_SECONDS: f64 = 10.0;
/// How long a kept-alive connection may wait for its next request: longer than nginx's
/// upstream keep-alive (60 s), so that the proxy closes first and never reuses a
/// connection we closed.
pub const DEFAULT_IDLE_TIMEOUT_SECONDS: f64 = 75.0;

/// `raytile serve`: the HTTP service (`docs/spec/http.md`).
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Address and port to listen on (port 0 picks a free one).
    #[arg(long, env = "RAYTILE_ADDR", default_value = DEFAULT_ADDR)]
    pub addr: SocketAddr,

    /// Largest image, in pixels (width × height of the full frame).
    #[arg(long, env = "RAYTILE_MAX_PIXELS", default_value_t = Limits::default().max_pixels)]
    pub max_pixels: u64,

    /// Largest `image.samples` (a pixel traces samples² rays).
    #[arg(long, env = "RAYTILE_MAX_SAMPLES", default_value_t = Limits::default().max_samples)]
    pub max_samples: u32,

    /// Largest `max_depth` (reflection and refraction recursion), at most 100.
    #[arg(long, env = "RAYTILE_MAX_DEPTH", default_value_t = Limits::default().max_depth)]
    pub max_depth: u32,

    /// Most objects in a scene.
    #[arg(long, env = "RAYTILE_MAX_OBJECTS", default_value_t = Limits::default().max_objects)]
    pub max_objects: u64,

    /// Most mesh triangles in a scene, over all meshes.
    #[arg(long, env = "RAYTILE_MAX_TRIANGLES", default_value_t = Limits::default().max_triangles)]
    pub max_triangles: u64,

    /// Most rays a render may be estimated to trace (a pilot traces a sparse grid of its
    /// pixels); past it, 422. A render that traces half as much again is stopped.
    #[arg(long, env = "RAYTILE_MAX_RAYS", default_value_t = DEFAULT_MAX_RAYS, value_parser = clap::value_parser!(u64).range(1..))]
    pub max_rays: u64,

    /// Largest request body in bytes; larger ones get 413.
    #[arg(long, env = "RAYTILE_MAX_BODY_BYTES", default_value_t = DEFAULT_MAX_BODY_BYTES)]
    pub max_body_bytes: usize,

    /// Memory budget in bytes (`805306368`, or with a unit: `768MiB`, `1GiB`, `512MB`):
    /// every request is charged its worst case before it allocates; what can never fit
    /// gets 413 or 422, what does not fit now waits in the queue or gets 503. Size it as
    /// the container's memory limit less a quarter (`docs/deploy.md`).
    #[arg(long, env = "RAYTILE_MEMORY_BYTES", default_value = "768MiB", value_parser = parse_bytes)]
    pub memory_bytes: u64,

    /// The most the cache of grading references may hold, in bytes like `--memory-bytes`
    /// (`0`: no cache; default a quarter of `--memory-bytes`). Its entries are reserved
    /// in the memory budget and given back whenever a request needs the room.
    #[arg(long, env = "RAYTILE_REFERENCE_CACHE_BYTES", value_parser = parse_cache_bytes)]
    pub reference_cache_bytes: Option<u64>,

    /// Renders admitted to trace at once (default: one per core); they share the rayon
    /// threads, so more only adds latency to each.
    #[arg(long, env = "RAYTILE_MAX_RENDERS", value_parser = clap::value_parser!(u32).range(1..))]
    pub max_renders: Option<u32>,

    /// Requests allowed to wait for a render slot; past that, 503 at once.
    #[arg(long, env = "RAYTILE_QUEUE", default_value_t = DEFAULT_QUEUE)]
    pub queue: usize,

    /// Seconds a request may take in all (fractions allowed). Past it before the first
    /// byte: 504; after the first byte the stream is cut.
    #[arg(long, env = "RAYTILE_DEADLINE_SECONDS", default_value_t = DEFAULT_DEADLINE_SECONDS, value_parser = parse_seconds)]
    pub deadline_seconds: f64,

    /// Rayon worker threads that trace (default: one per core).
    #[arg(long, env = "RAYTILE_THREADS", value_parser = clap::value_parser!(u32).range(1..))]
    pub threads: Option<u32>,

    /// Seconds in-flight responses may run on after SIGTERM or Ctrl-C before they are cut.
    #[arg(long, env = "RAYTILE_GRACE_SECONDS", default_value_t = DEFAULT_GRACE_SECONDS, value_parser = parse_seconds)]
    pub grace_seconds: f64,

    /// Seconds a response may wait for a client that takes nothing before its render is
    /// stopped: a client that stops reading must not hold the trace threads.
    #[arg(long, env = "RAYTILE_STALL_SECONDS", default_value_t = DEFAULT_STALL_SECONDS, value_parser = parse_seconds)]
    pub stall_seconds: f64,

    /// Connections open at once (lowered at start to fit the file-descriptor limit); at
    /// the cap a client that speaks displaces a silent or idle connection, and gets 503
    /// with `Retry-After` only when every connection has a request in flight.
    #[arg(long, env = "RAYTILE_MAX_CONNECTIONS", default_value_t = DEFAULT_MAX_CONNECTIONS, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    pub max_connections: u32,

    /// Seconds a request's head (request line and headers) may take from its first
    /// byte, and a new connection may take to send one; slower clients are cut.
    #[arg(long, env = "RAYTILE_HEADER_TIMEOUT_SECONDS", default_value_t = DEFAULT_HEADER_TIMEOUT_SECONDS, value_parser = parse_seconds)]
    pub header_timeout_seconds: f64,

    /// Seconds a kept-alive connection with no request in flight stays open. Keep it
    /// longer than the proxy's upstream keep-alive (nginx: 60 s).
    #[arg(long, env = "RAYTILE_IDLE_TIMEOUT_SECONDS", default_value_t = DEFAULT_IDLE_TIMEOUT_SECONDS, value_parser = parse_seconds)]
    pub idle_timeout_seconds: f64,

    /// Tile edge in pixels.
    #[arg(long, env = "RAYTILE_TILE", default_value_t = DEFAULT_TILE_PX, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub tile: u32,

    /// Log format: `text` for people, `json` for log collectors.
    #[arg(long, env = "RAYTILE_LOG_FORMAT", default_value = "text", value_parser = ["text", "json"])]
    pub log_format: String,

    /// Largest frame, in pixels, whose failing submissions are diagnosed (0: never).
    #[arg(long, env = "RAYTILE_DIAGNOSIS_MAX_PIXELS", default_value_t = crate::grade::diagnose::DEFAULT_MAX_PIXELS)]
    pub diagnosis_max_pixels: u64,

    /// Require an instructor's bearer token on the routes that take a posted scene
    /// (`/v1/render`, `/v1/hits`, `/v1/trace`, `/v1/validate`, `/v1/grade`): what a
    /// course deployment must set, or anyone can render the answer key.
    #[arg(long, env = "RAYTILE_REQUIRE_TOKEN")]
    pub require_token: bool,

    /// An instructor token accepted besides those in the database, to bootstrap a
    /// deployment. Set it in the environment, not on the command line, where `ps` shows it.
    #[arg(long, env = "RAYTILE_ADMIN_TOKEN", hide_env_values = true)]
    pub admin_token: Option<crate::store::Secret>,

    /// Submissions a student may make to one assignment in any hour (0: no limit).
    /// Each verdict tells something of the reference; counted in the database, so the
    /// limit holds across replicas.
    #[arg(long, env = "RAYTILE_SUBMISSIONS_PER_HOUR", default_value_t = DEFAULT_SUBMISSIONS_PER_HOUR)]
    pub submissions_per_hour: u32,

    /// Where tokens, assignments and submissions are kept.
    #[command(flatten)]
    pub store: StoreArgs,
}

/// Where the database is: embedded SQLite in `--data-dir` unless `--database` names a
/// PostgreSQL server (shared by every replica).
#[derive(Debug, Clone, clap::Args)]
pub struct StoreArgs {
    /// The data folder; the embedded SQLite database (`raytile.db`) is created there on
    /// first use.
    #[arg(long, env = "RAYTILE_DATA_DIR", default_value = DEFAULT_DATA_DIR)]
    pub data_dir: std::path::PathBuf,

    /// A PostgreSQL URL (`postgres://user:password@host/db`); instead of `--data-dir`.
    #[arg(long, env = "RAYTILE_DATABASE_URL", hide_env_values = true)]
    pub database: Option<crate::store::Secret>,
}

/// Submissions a student may make to one assignment in an hour, unless told otherwise:
/// enough to fix and resubmit through a session, few enough that the verdicts cannot
/// be used to search for the reference.
pub const DEFAULT_SUBMISSIONS_PER_HOUR: u32 = 30;

/// The data folder unless told otherwise.
pub const DEFAULT_DATA_DIR: &str = "./raytile-data";

impl StoreArgs {
    /// Opens the database these settings name (creating and migrating it on first use).
    pub async fn open(&self) -> Result<crate::store::Store, crate::store::StoreError> {
        crate::store::Store::open(self.database.as_ref(), &self.data_dir).await
    }
}

impl Default for StoreArgs {
    fn default() -> Self {
        StoreArgs {
            data_dir: DEFAULT_DATA_DIR.into(),
            database: None,
        }
    }
}

impl Default for ServeArgs {
    /// The defaults of every flag, ignoring the environment (tests start from these).
    fn default() -> Self {
        let limits = Limits::default();
        ServeArgs {
            addr: DEFAULT_ADDR
                .parse()
                .unwrap_or_else(|_| ([0, 0, 0, 0], 8080).into()),
            max_pixels: limits.max_pixels,
            max_samples: limits.max_samples,
            max_depth: limits.max_depth,
            max_objects: limits.max_objects,
            max_triangles: limits.max_triangles,
            max_rays: DEFAULT_MAX_RAYS,
            max_body_bytes: DEFAULT_MAX_BODY_BYTES,
            memory_bytes: DEFAULT_MEMORY_BYTES,
            reference_cache_bytes: None,
            max_renders: None,
            queue: DEFAULT_QUEUE,
            deadline_seconds: DEFAULT_DEADLINE_SECONDS,
            threads: None,
            grace_seconds: DEFAULT_GRACE_SECONDS,
            stall_seconds: DEFAULT_STALL_SECONDS,
            max_connections: DEFAULT_MAX_CONNECTIONS,
            header_timeout_seconds: DEFAULT_HEADER_TIMEOUT_SECONDS,
            idle_timeout_seconds: DEFAULT_IDLE_TIMEOUT_SECONDS,
            tile: DEFAULT_TILE_PX,
            log_format: "text".into(),
            diagnosis_max_pixels: crate::grade::diagnose::DEFAULT_MAX_PIXELS,
            require_token: false,
            admin_token: None,
            submissions_per_hour: DEFAULT_SUBMISSIONS_PER_HOUR,
            store: StoreArgs::default(),
        }
    }
}

impl ServeArgs {
    /// The configuration from the environment alone (for `raytile` with no command).
    pub fn from_env() -> Result<ServeArgs, clap::Error> {
        #[derive(clap::Parser)]
        struct Env {
            #[command(flatten)]
            args: ServeArgs,
        }
        <Env as clap::Parser>::try_parse_from(["raytile"]).map(|e| e.args)
    }

    /// The scene limits that requests are checked against.
    pub fn limits(&self) -> Limits {
        Limits {
            max_pixels: self.max_pixels,
            max_samples: self.max_samples,
            max_depth: self.max_depth,
            max_objects: self.max_objects,
            max_triangles: self.max_triangles,
        }
    }

    /// Renders tracing at once: the flag, or the number of cores.
    pub fn max_renders(&self) -> usize {
        self.max_renders.map_or_else(cores, |n| n as usize)
    }

    /// Rayon threads: the flag, or the number of cores.
    pub fn threads(&self) -> usize {
        self.threads.map_or_else(cores, |n| n as usize)
    }

    /// The per-request deadline.
    pub fn deadline(&self) -> Duration {
        Duration::from_secs_f64(self.deadline_seconds)
    }

    /// How long a response waits for a client that takes nothing.
    pub fn stall(&self) -> Duration {
        Duration::from_secs_f64(self.stall_seconds)
    }

    /// What each connection may hold: the cap and the two timeouts.
    pub fn connection_limits(&self) -> ConnectionLimits {
        ConnectionLimits {
            max_connections: self.max_connections as usize,
            header_timeout: Duration::from_secs_f64(self.header_timeout_seconds),
            idle_timeout: Duration::from_secs_f64(self.idle_timeout_seconds),
        }
    }

    /// The shutdown grace period.
    pub fn grace(&self) -> Duration {
        Duration::from_secs_f64(self.grace_seconds)
    }

    /// The reference cache's capacity: the flag, else a quarter of the memory budget;
    /// never more than the budget.
    pub fn reference_cache_bytes(&self) -> u64 {
        self.reference_cache_bytes
            .unwrap_or(self.memory_bytes / 4)
            .min(self.memory_bytes)
    }

    /// The smallest memory budget these settings allow: two bodies of
    /// `--max-body-bytes` (one read, one copy as a route parses it) and
    /// [`MIN_MEMORY_HEADROOM_BYTES`]; less, and a request within the body limit could be
    /// refused for its size alone.
    pub fn min_memory_bytes(&self) -> u64 {
        (self.max_body_bytes as u64)
            .saturating_mul(2)
            .saturating_add(MIN_MEMORY_HEADROOM_BYTES)
    }

    /// Checks what parsing each flag cannot: that `--memory-bytes` holds the largest
    /// body, and that `--max-depth` is within what the renderer traces
    /// ([`DEEPEST`]).
    pub fn check(&self) -> Result<(), String> {
        if self.max_depth > DEEPEST {
            return Err(format!(
                "--max-depth {} is more than {DEEPEST}, the deepest recursion the renderer \
                 traces (each bounce takes room on a trace thread's stack)",
                self.max_depth
            ));
        }
        let min = self.min_memory_bytes();
        if self.memory_bytes < min {
            return Err(format!(
                "--memory-bytes {} is too small: with --max-body-bytes {} it must be at least \
                 {min} bytes ({} MiB: two bodies and {} MiB); raise it or lower \
                 --max-body-bytes",
                self.memory_bytes,
                self.max_body_bytes,
                min.div_ceil(1 << 20),
                MIN_MEMORY_HEADROOM_BYTES >> 20,
            ));
        }
        Ok(())
    }
}

/// What each connection may hold (see `server::connection`).
#[derive(Debug, Clone, Copy)]
pub struct ConnectionLimits {
    /// Connections open at once.
    pub max_connections: usize,
    /// From a request's first byte to the end of its head; and from accept to the
    /// first byte.
    pub header_timeout: Duration,
    /// A kept-alive connection with nothing in flight.
    pub idle_timeout: Duration,
}

/// The cores this process may use.
fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Seconds as a positive, finite number (`300`, `0.5`), at most a year.
pub(crate) fn parse_seconds(s: &str) -> Result<f64, String> {
    let x: f64 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number of seconds"))?;
    if x.is_finite() && x > 0.0 && x <= 365.0 * 86_400.0 {
        Ok(x)
    } else {
        Err(format!(
            "`{s}`: seconds must be more than 0 and at most a year"
        ))
    }
}

/// `0`, or a number of bytes as [`parse_bytes`] reads it.
fn parse_cache_bytes(s: &str) -> Result<u64, String> {
    if s.trim() == "0" {
        return Ok(0);
    }
    parse_bytes(s)
}

/// A number of bytes, plain or with a unit: `KiB`, `MiB`, `GiB` (powers of 1024), `kB`,
/// `MB`, `GB` (powers of 1000), `K`, `M`, `G` as Kubernetes' `Ki`, `Mi`, `Gi` too; at least
/// 1 MiB, at most 4 TiB (what the memory ledger can count).
pub(crate) fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let split = t.find(|c: char| !c.is_ascii_digit()).unwrap_or(t.len());
    let (digits, unit) = t.split_at(split);
    let scale: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "ki" | "kib" => 1 << 10,
        "m" | "mi" | "mib" => 1 << 20,
        "g" | "gi" | "gib" => 1 << 30,
        "kb" => 1_000,
        "mb" => 1_000_000,
        "gb" => 1_000_000_000,
        other => {
            return Err(format!(
                "`{s}`: unknown unit `{other}` (use KiB, MiB or GiB)"
            ));
        }
    };
    let n: u64 = digits
        .parse()
        .map_err(|_| format!("`{s}` is not a number of bytes"))?;
    let bytes = n
        .checked_mul(scale)
        .ok_or_else(|| format!("`{s}` is too large"))?;
    if !(1 << 20..=MAX_MEMORY_BYTES).contains(&bytes) {
        return Err(format!("`{s}`: must be at least 1 MiB and at most 4 TiB"));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_take_units_and_refuse_nonsense() {
        assert_eq!(parse_bytes("805306368"), Ok(768 << 20));
        assert_eq!(parse_bytes("768MiB"), Ok(768 << 20));
        assert_eq!(parse_bytes("1Gi"), Ok(1 << 30));
        assert_eq!(parse_bytes(" 512 MB "), Ok(512_000_000));
        for bad in [
            "",
            "MiB",
            "-1",
            "1.5GiB",
            "12 parsecs",
            "1000",
            "99999999TiB",
        ] {
            assert!(parse_bytes(bad).is_err(), "{bad}");
        }
    }

    /// A server set to admit scenes deeper than the renderer traces would have them
    /// refused one by one; it is refused at start instead, with the reason.
    #[test]
    fn a_max_depth_beyond_the_deepest_is_refused_at_start() {
        let mut c = ServeArgs {
            max_depth: DEEPEST,
            ..ServeArgs::default()
        };
        assert_eq!(c.check(), Ok(()));
        c.max_depth = DEEPEST + 1;
        let e = c.check().expect_err("a depth beyond the deepest");
        let want = format!("--max-depth {} is more than {DEEPEST}", DEEPEST + 1);
        assert!(e.starts_with(&want), "{e}");
    }

    #[test]
    fn the_reference_cache_is_a_quarter_of_the_budget_unless_told() {
        let mut c = ServeArgs::default();
        assert_eq!(c.reference_cache_bytes(), DEFAULT_MEMORY_BYTES / 4);
        c.reference_cache_bytes = Some(1 << 40);
        assert_eq!(c.reference_cache_bytes(), DEFAULT_MEMORY_BYTES);
        assert_eq!(parse_cache_bytes("0"), Ok(0));
        assert_eq!(parse_cache_bytes("64MiB"), Ok(64 << 20));
        assert!(parse_cache_bytes("12").is_err());
    }

    #[test]
    fn the_budget_must_hold_two_largest_bodies() {
        let mut c = ServeArgs::default();
        assert_eq!(c.check(), Ok(()));
        c.memory_bytes = 40 << 20;
        let e = c.check().unwrap_err();
        assert!(e.contains("--memory-bytes 41943040 is too small"), "{e}");
        assert!(e.contains("48 MiB"), "{e}");
        c.max_body_bytes = 1 << 20;
        assert_eq!(c.check(), Ok(()));
    }

    #[test]
    fn seconds_accept_fractions_and_refuse_nonsense() {
        assert_eq!(parse_seconds("0.5"), Ok(0.5));
        assert_eq!(parse_seconds("300"), Ok(300.0));
        for bad in ["0", "-1", "NaN", "inf", "soon", ""] {
            assert!(parse_seconds(bad).is_err(), "{bad}");
        }
    }
}
