//! `raytile render SCENE -o OUT.png --servers URL,URL,…`: one frame traced by several
//! raytile servers at once and assembled here into the PNG that a local `raytile render`
//! writes, byte for byte.
//!
//! It lives with the command line rather than in `render/` because it speaks HTTP, and
//! the renderer does not know HTTP exists.
//!
//! 1. The scene is read and validated here first, so a bad scene fails before any
//!    request leaves.
//! 2. [`split_bands`] cuts the frame (or `--region`) into full-width bands, a few per
//!    server so that a slow server holds up only a small part of the frame, each a whole
//!    number of tiles high so that the servers trace whole tiles.
//! 3. A scheduler keeps `--per-server` requests in flight on every server
//!    (`POST {url}/v1/render?region=x,y,w,h`), top band first. A server that fails a band
//!    (no connection, a timeout, a cut stream, 5xx, 429, 503, or a PNG that is not the
//!    band's) is paused by [`RetryPolicy::verdict`] (its `Retry-After`, else a doubling
//!    backoff), and the band goes back to the queue for a server that has not failed it
//!    yet (`pick`). A band that fails `--attempts` times, or an answer that any server
//!    would give (other 4xx: the scene or the request is wrong), stops the render with
//!    one line that names the band and the servers tried.
//! 4. Each band's PNG is decoded and handed to [`PngSink`] as one tile. The sink writes
//!    rows in order, one at a time, so the file grows while later bands are still out
//!    and its bytes depend only on the pixels.

use std::io::IsTerminal;
use std::path::Path;
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, bail};
use bytes::Bytes;
use indicatif::{ProgressBar, ProgressStyle};
use reqwest::StatusCode;
use reqwest::header::{ACCEPT, CONTENT_TYPE, RETRY_AFTER};
use tokio::task::JoinSet;
use tokio::time::Instant;

use super::TraceOptions;
use super::input::{read_input, scene_error};
use super::remote::{client_builder, server_url};
use crate::format::png::PngReader;
use crate::output::{OutputFile, PngSink};
use crate::render::{Rect, Tile, TileSink};
use crate::scene::{self, Limits};

/// The options of `raytile render` for rendering on servers.
#[derive(Debug, Clone, clap::Args)]
pub struct RemoteOptions {
    /// Render on these raytile servers instead of here: base URLs (`http://host:port`),
    /// comma-separated. A load balancer's URL works too (raise `--per-server` for it).
    #[arg(long, value_delimiter = ',', value_name = "URL,...")]
    pub servers: Vec<String>,
    /// Bands to cut the frame into per server: more spread the work better over servers
    /// of different speeds, fewer cost fewer requests.
    #[arg(long, default_value_t = 4, requires = "servers", value_parser = clap::value_parser!(u32).range(1..=64))]
    pub bands_per_server: u32,
    /// Requests in flight on each server at once.
    #[arg(long, default_value_t = 2, requires = "servers", value_parser = clap::value_parser!(u32).range(1..=64))]
    pub per_server: u32,
    /// Tries per band, over all servers, before the render fails.
    #[arg(long, default_value_t = 5, requires = "servers", value_parser = clap::value_parser!(u32).range(1..=100))]
    pub attempts: u32,
    /// Seconds one request may take, from connecting to the last byte of its PNG.
    #[arg(long, default_value_t = 300.0, requires = "servers", value_parser = crate::config::parse_seconds)]
    pub request_timeout_seconds: f64,
}

/// Longest wait for a TCP connection, whatever the request timeout: a server that does
/// not accept within it is down or unreachable, and another one should get the band.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);
/// Most bytes read of an error answer (a problem document is far smaller).
const ERROR_BODY_BYTES: usize = 64 * 1024;

/// Cuts `region` into full-width bands for about `count` requests: every band but the
/// last is the same whole number of `tile_px` rows high (at least one tile row), top to
/// bottom, covering the region exactly once. Fewer bands come back when the region has
/// fewer tile rows than `count`.
pub fn split_bands(region: Rect, tile_px: u32, count: u32) -> Vec<Rect> {
    if region.width == 0 || region.height == 0 {
        return Vec::new();
    }
    let tile = tile_px.max(1);
    let rows = region.height.div_ceil(count.max(1));
    let band_px = rows
        .div_ceil(tile)
        .saturating_mul(tile)
        .min(region.height)
        .max(1);
    let mut out = Vec::new();
    let mut y = 0;
    while y < region.height {
        let h = band_px.min(region.height - y);
        out.push(Rect {
            x: region.x,
            y: region.y + y,
            width: region.width,
            height: h,
        });
        y += h;
    }
    out
}

/// Why one request for a band failed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Failure {
    /// No whole answer: no connection, a timeout, or the stream was cut.
    Transport(String),
    /// An HTTP status other than 200.
    Status {
        /// The status code.
        status: u16,
        /// The server's `Retry-After`, when it sent one in seconds.
        retry_after: Option<Duration>,
        /// What the answer's body said, on one line.
        detail: String,
    },
    /// A 200 whose body is not this band's PNG.
    BadAnswer(String),
    /// Not the server's doing: the output could not be written here.
    Local(String),
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::Transport(m) | Failure::Local(m) => f.write_str(m),
            Failure::BadAnswer(m) => write!(f, "answered with {m}"),
            Failure::Status { status, detail, .. } => {
                let reason = StatusCode::from_u16(*status)
                    .ok()
                    .and_then(|s| s.canonical_reason())
                    .unwrap_or("");
                write!(f, "answered {status} {reason}")?;
                if !detail.is_empty() {
                    write!(f, ": {detail}")?;
                }
                Ok(())
            }
        }
    }
}

/// What to do after a failure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// Try the band again, on another server if there is one, and give this server no
    /// new band for `pause`.
    Retry {
        /// How long the failing server is left alone.
        pause: Duration,
    },
    /// Stop the render: every server would answer the same, or the fault is here.
    Stop,
}

/// How failed requests are retried. Pure, so that it is tested without a network.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RetryPolicy {
    /// Tries per band, over all servers, before giving up.
    pub attempts: u32,
    /// A server's pause after its first failure without `Retry-After`; it doubles with
    /// each further failure in a row.
    pub base_backoff: Duration,
    /// The longest such pause.
    pub max_backoff: Duration,
    /// The longest `Retry-After` honoured: a server that asks for more is paused this
    /// long, so one answer cannot stall the frame for hours.
    pub max_retry_after: Duration,
}

impl RetryPolicy {
    /// `attempts` tries per band; pauses from 100 ms doubling to 5 s, `Retry-After` up to
    /// 30 s.
    pub fn new(attempts: u32) -> RetryPolicy {
        RetryPolicy {
            attempts: attempts.max(1),
            base_backoff: Duration::from_millis(100),
            max_backoff: Duration::from_secs(5),
            max_retry_after: Duration::from_secs(30),
        }
    }

    /// The pause after `failures_in_a_row` (≥ 1) failures of one server.
    pub fn backoff(&self, failures_in_a_row: u32) -> Duration {
        let doublings = failures_in_a_row.saturating_sub(1).min(20);
        self.base_backoff
            .saturating_mul(1 << doublings)
            .min(self.max_backoff)
    }

    /// What to do after `failure`, the `failures_in_a_row`-th of its server.
    pub fn verdict(&self, failure: &Failure, failures_in_a_row: u32) -> Verdict {
        match failure {
            Failure::Transport(_) | Failure::BadAnswer(_) => Verdict::Retry {
                pause: self.backoff(failures_in_a_row),
            },
            Failure::Status {
                status,
                retry_after,
                ..
            } if is_retryable(*status) => Verdict::Retry {
                pause: retry_after.map_or_else(
                    || self.backoff(failures_in_a_row),
                    |d| d.min(self.max_retry_after),
                ),
            },
            Failure::Status { .. } | Failure::Local(_) => Verdict::Stop,
        }
    }

    /// Whether a band that has failed `failures` times is given up.
    pub fn gives_up(&self, failures: u32) -> bool {
        failures >= self.attempts
    }
}

/// Statuses that another server, or the same one later, may answer differently: 408
/// (too slow to send), 429 and 503 (busy), and every other 5xx (the server's fault).
/// Other 4xx say the request is wrong, which no retry changes.
pub fn is_retryable(status: u16) -> bool {
    status == 408 || status == 429 || (500..600).contains(&status)
}

/// `Retry-After` in seconds (`"3"`). The HTTP-date form gives `None`: the backoff
/// applies instead.
pub fn parse_retry_after(value: &str) -> Option<Duration> {
    value.trim().parse::<u64>().ok().map(Duration::from_secs)
}

/// A band waiting for a server, and what happened to it so far.
#[derive(Debug, Clone)]
struct Job {
    rect: Rect,
    failures: u32,
    /// Per server: whether it failed this band.
    failed_on: Vec<bool>,
    /// Servers tried, in order (for the message when the band is given up).
    tried: Vec<usize>,
    /// The last failure, with its server.
    last: String,
}

impl Job {
    fn new(rect: Rect, servers: usize) -> Job {
        Job {
            rect,
            failures: 0,
            failed_on: vec![false; servers],
            tried: Vec::new(),
            last: String::new(),
        }
    }
}

/// One server as the scheduler sees it.
#[derive(Debug, Clone, Default)]
struct ServerSlot {
    in_flight: u32,
    paused_until: Option<Instant>,
    failures_in_a_row: u32,
}

impl ServerSlot {
    fn free(&self, per_server: u32, now: Instant) -> bool {
        self.in_flight < per_server && self.paused_until.is_none_or(|t| t <= now)
    }
}

/// The next band to start at `now` and the server for it, as indices: the top-most
/// waiting band that some free server (not paused, below `per_server` in flight) has not
/// failed, on the least busy such server. A band that every server has failed may go to
/// any of them. Bands that must wait for a busy server are passed over for later ones.
fn pick(
    jobs: &[Job],
    servers: &[ServerSlot],
    per_server: u32,
    now: Instant,
) -> Option<(usize, usize)> {
    jobs.iter().enumerate().find_map(|(j, job)| {
        let anyone = job.failed_on.iter().all(|f| *f);
        servers
            .iter()
            .enumerate()
            .filter(|(s, slot)| slot.free(per_server, now) && (anyone || !job.failed_on[*s]))
            .min_by_key(|(s, slot)| (slot.in_flight, *s))
            .map(|(s, _)| (j, s))
    })
}

/// When a paused server with room frees up, if any band waits for it.
fn next_wake(jobs: &[Job], servers: &[ServerSlot], per_server: u32) -> Option<Instant> {
    if jobs.is_empty() {
        return None;
    }
    servers
        .iter()
        .filter(|s| s.in_flight < per_server)
        .filter_map(|s| s.paused_until)
        .min()
}

/// The band writer all requests share.
type Sink = PngSink<OutputFile>;

/// What the requests need, cheap to clone into each.
#[derive(Clone)]
struct Remote {
    client: reqwest::Client,
    scene: Bytes,
    sink: Arc<Sink>,
}

/// What a finished frame counted (for `--stats`).
#[derive(Debug, Default)]
struct Summary {
    requests: u64,
    retries: u64,
    bands_by_server: Vec<u64>,
}

/// `raytile render … --servers …`.
pub fn render(
    opts: &TraceOptions,
    output: &Path,
    remote: &RemoteOptions,
) -> anyhow::Result<ExitCode> {
    let t0 = std::time::Instant::now();
    let bytes = read_input(&opts.scene)?;
    let scene = scene::parse(&bytes, &Limits::NONE).map_err(|e| scene_error(&opts.scene, e))?;
    let region = opts.region_in(&scene)?;
    let servers = remote
        .servers
        .iter()
        .map(|s| server_url(s))
        .collect::<anyhow::Result<Vec<String>>>()?;
    if servers.is_empty() {
        bail!("--servers needs at least one URL");
    }
    let count = u32::try_from(servers.len())
        .unwrap_or(u32::MAX)
        .saturating_mul(remote.bands_per_server);
    let bands = split_bands(region, opts.tile, count);
    let band_px = bands.first().map_or(1, |b| b.height);
    let timeout = Duration::from_secs_f64(remote.request_timeout_seconds);
    let client = client_builder()
        .timeout(timeout)
        .connect_timeout(CONNECT_TIMEOUT.min(timeout))
        .build()
        .context("cannot set up the HTTP client")?;

    let file = OutputFile::create(output)
        .with_context(|| format!("cannot create {}", output.display()))?;
    let summary = match render_into(file, region, &bands, &servers, client, bytes, remote) {
        Ok(s) => s,
        Err(e) => {
            // No half-written image is left behind to be mistaken for a whole one.
            let _ = std::fs::remove_file(output);
            return Err(e);
        }
    };
    if opts.stats {
        let line = serde_json::json!({
            "command": "render",
            "servers": servers,
            "width": region.width,
            "height": region.height,
            "bands": bands.len(),
            "band_height": band_px,
            "requests": summary.requests,
            "retries": summary.retries,
            "bands_by_server": summary.bands_by_server,
            "total_s": t0.elapsed().as_secs_f64(),
        });
        eprintln!("{line}");
    }
    Ok(ExitCode::SUCCESS)
}

/// Renders `bands` of `region` on `servers` into a PNG written to `file`.
fn render_into(
    file: OutputFile,
    region: Rect,
    bands: &[Rect],
    servers: &[String],
    client: reqwest::Client,
    scene: Vec<u8>,
    remote: &RemoteOptions,
) -> anyhow::Result<Summary> {
    // One thread is plenty to drive the requests; decoding runs on blocking threads.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let ctx = Remote {
        client,
        scene: Bytes::from(scene),
        sink: Arc::new(PngSink::new(file.clone(), region).context("cannot start the PNG")?),
    };
    let bar = progress_bar(bands.len() as u64);
    let summary = runtime.block_on(run_bands(
        &ctx,
        servers,
        bands.to_vec(),
        RetryPolicy::new(remote.attempts),
        remote.per_server,
        bar.as_ref(),
    ));
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    let summary = summary?;
    // Every request has finished (run_bands returns only then), so this is the last
    // reference to the sink.
    let sink = Arc::try_unwrap(ctx.sink)
        .map_err(|_| anyhow::anyhow!("internal error: a region was still being written"))?;
    sink.finish().context("cannot finish the PNG")?;
    file.commit().context("cannot finish the PNG")?;
    Ok(summary)
}

fn progress_bar(bands: u64) -> Option<ProgressBar> {
    std::io::stderr().is_terminal().then(|| {
        let b = ProgressBar::new(bands);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} regions  {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        b
    })
}

/// Says something on standard error without tearing the progress bar.
fn note(bar: Option<&ProgressBar>, line: String) {
    match bar {
        Some(b) => b.println(line),
        None => eprintln!("{line}"),
    }
}

/// Renders every band on the servers into `ctx.sink`: the scheduler of the module doc.
async fn run_bands(
    ctx: &Remote,
    servers: &[String],
    bands: Vec<Rect>,
    policy: RetryPolicy,
    per_server: u32,
    bar: Option<&ProgressBar>,
) -> anyhow::Result<Summary> {
    let mut waiting: Vec<Job> = bands
        .into_iter()
        .map(|r| Job::new(r, servers.len()))
        .collect();
    let mut slots = vec![ServerSlot::default(); servers.len()];
    let mut summary = Summary {
        bands_by_server: vec![0; servers.len()],
        ..Summary::default()
    };
    // Dropped on every return, which aborts the requests still in flight.
    let mut tasks = JoinSet::new();
    loop {
        while let Some((j, s)) = pick(&waiting, &slots, per_server, Instant::now()) {
            let job = waiting.remove(j);
            slots[s].in_flight += 1;
            summary.requests += 1;
            let (ctx, url) = (ctx.clone(), servers[s].clone());
            tasks.spawn(async move {
                let result = fetch_band(&ctx, &url, job.rect).await;
                (s, job, result)
            });
        }
        if tasks.is_empty() && waiting.is_empty() {
            return Ok(summary);
        }
        let wake = next_wake(&waiting, &slots, per_server);
        if tasks.is_empty() && wake.is_none() {
            // pick() leaves a band waiting only for a busy or a paused server.
            bail!("internal error: bands wait, but no server is busy or paused");
        }
        let joined = tokio::select! {
            joined = tasks.join_next(), if !tasks.is_empty() => joined,
            () = tokio::time::sleep_until(wake.unwrap_or_else(Instant::now)), if wake.is_some() => None,
        };
        let Some(joined) = joined else { continue };
        let (s, mut job, result) = joined.context("a band request stopped unexpectedly")?;
        let slot = &mut slots[s];
        slot.in_flight -= 1;
        let failure = match result {
            Ok(()) => {
                slot.failures_in_a_row = 0;
                summary.bands_by_server[s] += 1;
                if let Some(b) = bar {
                    b.inc(1);
                }
                continue;
            }
            Err(f) => f,
        };
        slot.failures_in_a_row += 1;
        job.failures += 1;
        job.failed_on[s] = true;
        job.tried.push(s);
        job.last = format!("{}: {failure}", servers[s]);
        let band = job.rect.to_string();
        let pause = match policy.verdict(&failure, slot.failures_in_a_row) {
            Verdict::Stop if matches!(failure, Failure::Local(_)) => {
                bail!("cannot write region {band}: {failure}")
            }
            Verdict::Stop => bail!("region {band}: {}", job.last),
            Verdict::Retry { pause } => pause,
        };
        if policy.gives_up(job.failures) {
            let mut tried: Vec<&str> = Vec::new();
            for &t in &job.tried {
                if !tried.contains(&servers[t].as_str()) {
                    tried.push(&servers[t]);
                }
            }
            bail!(
                "region {band} failed {} times (servers tried: {}); last: {}",
                job.failures,
                tried.join(", "),
                job.last
            );
        }
        slot.paused_until = Some(Instant::now() + pause);
        summary.retries += 1;
        note(
            bar,
            format!(
                "raytile: region {band}: {}; retrying ({} of {} tries used)",
                job.last, job.failures, policy.attempts
            ),
        );
        if let Some(b) = bar {
            b.set_message(format!("{} retried", summary.retries));
        }
        // Back in top-to-bottom order: the sink can only write rows past this band once
        // it is in.
        let at = waiting.partition_point(|w| w.rect.y < job.rect.y);
        waiting.insert(at, job);
    }
}

/// One request: the band's PNG from `url`, decoded and handed to the sink.
async fn fetch_band(ctx: &Remote, url: &str, rect: Rect) -> Result<(), Failure> {
    let mut res = ctx
        .client
        .post(format!("{url}/v1/render?region={rect}"))
        .header(CONTENT_TYPE, "application/json")
        .header(ACCEPT, "image/png")
        .body(ctx.scene.clone())
        .send()
        .await
        .map_err(transport)?;
    let status = res.status();
    if status != StatusCode::OK {
        let retry_after = res
            .headers()
            .get(RETRY_AFTER)
            .and_then(|v| v.to_str().ok())
            .and_then(parse_retry_after);
        // The error's body only explains; a failure to read it changes nothing.
        let body = read_body(&mut res, ERROR_BODY_BYTES)
            .await
            .unwrap_or_default();
        return Err(Failure::Status {
            status: status.as_u16(),
            retry_after,
            detail: explain(&body),
        });
    }
    let body = read_body(&mut res, png_limit_bytes(rect)).await?;
    let sink = ctx.sink.clone();
    // Decoding and re-encoding are CPU work: off the thread that drives the requests.
    tokio::task::spawn_blocking(move || {
        let pixels = decode_band(&body, rect).map_err(Failure::BadAnswer)?;
        sink.tile(Tile {
            rect,
            pixels,
            rays: 0,
        })
        .map_err(|e| Failure::Local(e.to_string()))
    })
    .await
    .map_err(|e| Failure::Local(format!("decoding stopped: {e}")))?
}

/// The body, or a failure once it passes `limit` bytes (a server cannot fill our memory).
async fn read_body(res: &mut reqwest::Response, limit: usize) -> Result<Vec<u8>, Failure> {
    let mut body = Vec::new();
    while let Some(chunk) = res.chunk().await.map_err(transport)? {
        if body.len() + chunk.len() > limit {
            return Err(Failure::BadAnswer(format!("more than {limit} bytes")));
        }
        body.extend_from_slice(&chunk);
    }
    Ok(body)
}

/// Generous bound on a band's PNG: raw RGB twice over, plus room for headers.
fn png_limit_bytes(rect: Rect) -> usize {
    usize::try_from(rect.pixels())
        .unwrap_or(usize::MAX)
        .saturating_mul(6)
        .saturating_add(1 << 20)
}

/// A reqwest error as one line, without the URL (the caller names the server).
pub fn transport(e: reqwest::Error) -> Failure {
    let e = e.without_url();
    let mut root: &dyn std::error::Error = &e;
    while let Some(next) = root.source() {
        root = next;
    }
    Failure::Transport(if e.is_timeout() {
        "timed out".to_owned()
    } else if e.is_connect() {
        format!("cannot connect ({root})")
    } else if e.is_body() || e.is_decode() {
        format!("the answer was cut off ({root})")
    } else {
        format!("{e} ({root})")
    })
}

/// An error answer's body on one line: a problem document's title, detail and problems,
/// else the start of the text.
fn explain(body: &[u8]) -> String {
    let one_line = |s: &str| s.split_whitespace().collect::<Vec<_>>().join(" ");
    let Ok(doc) = serde_json::from_slice::<serde_json::Value>(body) else {
        let text = one_line(&String::from_utf8_lossy(body));
        return text.chars().take(200).collect();
    };
    let mut parts: Vec<String> = ["title", "detail"]
        .iter()
        .filter_map(|k| doc.get(*k).and_then(|v| v.as_str()))
        .map(one_line)
        .collect();
    if let Some(problems) = doc.get("problems").and_then(|p| p.as_array()) {
        let list: Vec<String> = problems
            .iter()
            .map(|p| {
                let field = |k| {
                    p.get(k)
                        .and_then(|v: &serde_json::Value| v.as_str())
                        .unwrap_or("")
                };
                format!("{} {}", field("pointer"), one_line(field("message")))
            })
            .collect();
        parts.push(list.join("; "));
    }
    parts.join(": ")
}

/// Decodes a band's PNG, checking that it is the 8-bit RGB image of `rect`'s size.
pub fn decode_band(bytes: &[u8], rect: Rect) -> Result<Vec<[u8; 3]>, String> {
    let raw = usize::try_from(rect.pixels())
        .unwrap_or(usize::MAX)
        .saturating_mul(3);
    // Room for the image and the decoder's own buffers, and no more: the header is
    // checked against the band before the image is allocated.
    let limit = raw.saturating_mul(2).saturating_add(8 << 20);
    let png =
        PngReader::new(bytes, limit).map_err(|e| format!("something that is not a PNG ({e})"))?;
    let (w, h) = png.size();
    if (w, h) != (rect.width, rect.height) {
        return Err(format!(
            "a {w} × {h} PNG for a {} × {} region",
            rect.width, rect.height
        ));
    }
    if !png.is_rgb8() {
        return Err("a PNG that is not 8-bit RGB".into());
    }
    let image = png.decode().map_err(|e| format!("a broken PNG ({e})"))?;
    Ok(image.pixels())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x: u32, y: u32, width: u32, height: u32) -> Rect {
        Rect {
            x,
            y,
            width,
            height,
        }
    }

    #[test]
    fn bands_cover_the_region_once_in_whole_tiles() {
        for (region, tile, count) in [
            (rect(0, 0, 640, 480), 32, 8),
            (rect(0, 0, 640, 480), 32, 7),
            (rect(5, 17, 33, 101), 16, 3),
            (rect(0, 0, 10, 10), 32, 4),
            (rect(0, 0, 64, 64), 1, 1000),
            (rect(0, 0, 1, 1), 32, 1),
            (rect(3, 4, 100, 65), 32, 100),
        ] {
            let bands = split_bands(region, tile, count);
            assert!(!bands.is_empty());
            assert!(
                bands.len() as u32 <= count.max(1),
                "{region:?} {tile} {count}"
            );
            let mut y = region.y;
            for (i, b) in bands.iter().enumerate() {
                assert_eq!((b.x, b.width, b.y), (region.x, region.width, y));
                if i + 1 < bands.len() {
                    assert_eq!(b.height, bands[0].height, "equal bands but the last");
                    assert!(b.height % tile == 0, "whole tiles: {b:?}");
                } else {
                    assert!(b.height <= bands[0].height);
                }
                y += b.height;
            }
            assert_eq!(y, region.y + region.height, "{region:?} {tile} {count}");
        }
    }

    #[test]
    fn bands_are_a_few_per_server_when_the_frame_allows() {
        // 480 rows, 32-pixel tiles, 2 servers × 4: 60 rows → 64-row bands, 8 of them.
        let bands = split_bands(rect(0, 0, 640, 480), 32, 8);
        assert_eq!(bands.len(), 8);
        assert_eq!(bands[0].height, 64);
        assert_eq!(bands[7].height, 480 - 7 * 64);
        // Fewer tile rows than requests: one tile row each.
        assert_eq!(split_bands(rect(0, 0, 64, 96), 32, 10).len(), 3);
        // Smaller than a tile: one band.
        assert_eq!(
            split_bands(rect(0, 0, 8, 8), 32, 10),
            vec![rect(0, 0, 8, 8)]
        );
        assert!(split_bands(rect(0, 0, 0, 8), 32, 10).is_empty());
    }

    #[test]
    fn only_what_another_try_can_change_is_retried() {
        let p = RetryPolicy::new(5);
        let status = |status, retry_after| Failure::Status {
            status,
            retry_after,
            detail: String::new(),
        };
        for s in [408, 429, 500, 502, 503, 504] {
            assert!(
                matches!(p.verdict(&status(s, None), 1), Verdict::Retry { .. }),
                "{s}"
            );
        }
        for s in [400, 401, 404, 405, 406, 413, 415, 422] {
            assert_eq!(p.verdict(&status(s, None), 1), Verdict::Stop, "{s}");
        }
        assert!(matches!(
            p.verdict(&Failure::Transport("refused".into()), 1),
            Verdict::Retry { .. }
        ));
        assert!(matches!(
            p.verdict(&Failure::BadAnswer("a 1 × 1 PNG".into()), 1),
            Verdict::Retry { .. }
        ));
        assert_eq!(
            p.verdict(&Failure::Local("disk full".into()), 1),
            Verdict::Stop
        );
    }

    #[test]
    fn retry_after_is_honoured_up_to_a_bound_else_the_backoff_doubles() {
        let p = RetryPolicy::new(5);
        let busy = |retry_after| Failure::Status {
            status: 503,
            retry_after,
            detail: String::new(),
        };
        assert_eq!(
            p.verdict(&busy(Some(Duration::from_secs(2))), 1),
            Verdict::Retry {
                pause: Duration::from_secs(2)
            }
        );
        assert_eq!(
            p.verdict(&busy(Some(Duration::from_secs(86_400))), 1),
            Verdict::Retry {
                pause: p.max_retry_after
            }
        );
        assert_eq!(
            p.verdict(&busy(None), 3),
            Verdict::Retry {
                pause: Duration::from_millis(400)
            }
        );
        let pauses: Vec<u128> = (1..=8).map(|n| p.backoff(n).as_millis()).collect();
        assert_eq!(pauses, [100, 200, 400, 800, 1600, 3200, 5000, 5000]);
        assert_eq!(p.backoff(u32::MAX), p.max_backoff);
        assert_eq!(p.backoff(0), p.base_backoff);
    }

    #[test]
    fn attempts_are_bounded() {
        let p = RetryPolicy::new(3);
        assert!(!p.gives_up(2));
        assert!(p.gives_up(3));
        assert!(
            RetryPolicy::new(0).gives_up(1),
            "at least one try, and no more"
        );
    }

    #[test]
    fn retry_after_seconds_parse_and_dates_do_not() {
        assert_eq!(parse_retry_after("1"), Some(Duration::from_secs(1)));
        assert_eq!(parse_retry_after(" 120 "), Some(Duration::from_secs(120)));
        assert_eq!(parse_retry_after("Wed, 21 Oct 2015 07:28:00 GMT"), None);
        assert_eq!(parse_retry_after("-1"), None);
        assert_eq!(parse_retry_after(""), None);
    }

    fn job(failed_on: &[bool]) -> Job {
        Job {
            failed_on: failed_on.to_vec(),
            ..Job::new(rect(0, 0, 1, 1), failed_on.len())
        }
    }

    #[test]
    fn a_failed_band_goes_to_a_server_that_has_not_failed_it() {
        let now = Instant::now();
        let servers = vec![ServerSlot::default(); 2];
        // Band 0 failed on server 0: server 1 takes it, though server 0 is free too.
        assert_eq!(pick(&[job(&[true, false])], &servers, 2, now), Some((0, 1)));
        // Server 1 busy: band 0 waits for it, band 1 goes to server 0.
        let mut busy = servers.clone();
        busy[1].in_flight = 2;
        assert_eq!(
            pick(&[job(&[true, false]), job(&[false, false])], &busy, 2, now),
            Some((1, 0))
        );
        assert_eq!(pick(&[job(&[true, false])], &busy, 2, now), None);
        // Every server failed it: any free one may try again.
        assert_eq!(pick(&[job(&[true, true])], &busy, 2, now), Some((0, 0)));
    }

    #[test]
    fn paused_and_full_servers_get_nothing_and_the_least_busy_goes_first() {
        let now = Instant::now();
        let mut servers = vec![ServerSlot::default(); 3];
        servers[0].paused_until = Some(now + Duration::from_secs(1));
        servers[1].in_flight = 1;
        assert_eq!(pick(&[job(&[false; 3])], &servers, 2, now), Some((0, 2)));
        servers[2].in_flight = 2;
        assert_eq!(pick(&[job(&[false; 3])], &servers, 2, now), Some((0, 1)));
        servers[1].in_flight = 2;
        assert_eq!(pick(&[job(&[false; 3])], &servers, 2, now), None);
        // Only the paused server has room: wake when its pause ends.
        assert_eq!(
            next_wake(&[job(&[false; 3])], &servers, 2),
            servers[0].paused_until
        );
        assert_eq!(next_wake(&[], &servers, 2), None);
        // A pause that has ended is no pause.
        assert_eq!(
            pick(
                &[job(&[false; 3])],
                &servers,
                2,
                now + Duration::from_secs(2)
            ),
            Some((0, 0))
        );
    }

    #[test]
    fn a_band_must_be_the_png_asked_for() {
        let mut png_bytes = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut png_bytes, 2, 1);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().unwrap();
            w.write_image_data(&[1, 2, 3, 4, 5, 6]).unwrap();
        }
        assert_eq!(
            decode_band(&png_bytes, rect(7, 9, 2, 1)).unwrap(),
            vec![[1, 2, 3], [4, 5, 6]]
        );
        assert!(
            decode_band(&png_bytes, rect(0, 0, 1, 2))
                .unwrap_err()
                .contains("2 × 1")
        );
        assert!(decode_band(b"<html>busy</html>", rect(0, 0, 2, 1)).is_err());
        assert!(decode_band(&png_bytes[..png_bytes.len() - 20], rect(0, 0, 2, 1)).is_err());
    }

    #[test]
    fn error_bodies_are_explained_on_one_line() {
        let doc = br#"{"type":"x","title":"Invalid scene","status":422,
            "detail":"the scene has 1 problem(s)",
            "problems":[{"pointer":"/image/width","message":"must be\nat least 1"}]}"#;
        assert_eq!(
            explain(doc),
            "Invalid scene: the scene has 1 problem(s): /image/width must be at least 1"
        );
        assert_eq!(
            explain(b"<h1>502\nBad Gateway</h1>"),
            "<h1>502 Bad Gateway</h1>"
        );
        let status = Failure::Status {
            status: 503,
            retry_after: None,
            detail: "Saturated".into(),
        };
        assert_eq!(
            status.to_string(),
            "answered 503 Service Unavailable: Saturated"
        );
    }
}
