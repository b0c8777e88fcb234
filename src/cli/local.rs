//! `raytile render`, `raytile hits` and `raytile validate`: the renderer on local files,
//! with a progress bar on a terminal and `--stats` phase timings.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};

use super::TraceOptions;
use super::input::{load_scene, read_input};
use crate::format::{HitFormat, LinearImage, RasterFormat, exr, pfm};
use crate::output::{FrameSink, HitSink, OutputFile, PngSink};
use crate::render::{
    self, ColourKernel, HitKernel, Kernel, LinearKernel, Rect, Renderer, SinkClosed, Tile, TileSink,
};
use crate::scene::{self, Limits, SceneError};

/// `raytile render`.
#[derive(Debug, clap::Args)]
pub struct RenderArgs {
    #[command(flatten)]
    opts: TraceOptions,
    /// The image to write: a PNG (8-bit, gamma applied), or, named `.exr` or `.pfm`,
    /// a float image of the linear colours before gamma and quantisation.
    #[arg(short, long)]
    output: PathBuf,
    #[command(flatten, next_help_heading = "Rendering on servers")]
    remote: super::distributed::RemoteOptions,
}

/// `raytile hits`.
#[derive(Debug, clap::Args)]
pub struct HitsArgs {
    #[command(flatten)]
    opts: TraceOptions,
    /// The file to write: `.json`, `.ndjson`, `.npy` or `.csv`.
    #[arg(short, long)]
    output: PathBuf,
    /// The format, when the extension does not say.
    #[arg(long, value_parser = HitFormat::ALL.map(HitFormat::name))]
    format: Option<String>,
}

/// `raytile validate`.
#[derive(Debug, clap::Args)]
pub struct ValidateArgs {
    /// The scene file (JSON); `-` reads standard input.
    scene: PathBuf,
    /// Print the normalised scene (every default explicit) when it is valid.
    #[arg(long)]
    normalised: bool,
}

/// `raytile validate`.
pub fn validate(a: ValidateArgs) -> anyhow::Result<ExitCode> {
    let bytes = read_input(&a.scene)?;
    match scene::parse(&bytes, &Limits::NONE) {
        Ok(s) => {
            if a.normalised {
                println!("{}", serde_json::to_string_pretty(&s.normalised())?);
            } else {
                println!(
                    "{}: valid: {} × {} pixels, {}, {} objects, {} triangles, {} lights",
                    a.scene.display(),
                    s.width,
                    s.height,
                    scene::sample_grid(s.samples),
                    s.objects.len(),
                    s.triangles(),
                    s.lights.len()
                );
            }
            Ok(ExitCode::SUCCESS)
        }
        Err(SceneError::Invalid(problems)) => {
            println!(
                "{}: invalid, {} problem(s):",
                a.scene.display(),
                problems.len()
            );
            for p in problems {
                println!("  {p}");
            }
            Ok(ExitCode::from(1))
        }
        Err(e) => {
            println!("{}: {e}", a.scene.display());
            Ok(ExitCode::from(1))
        }
    }
}

/// `raytile render`: here, or with `--servers` on those servers.
pub fn render(a: RenderArgs) -> anyhow::Result<ExitCode> {
    let float = a
        .output
        .extension()
        .and_then(|e| e.to_str())
        .and_then(RasterFormat::from_name)
        .filter(|f| f.is_linear());
    if let Some(format) = float {
        if !a.remote.servers.is_empty() {
            anyhow::bail!(
                "float images ({}) are rendered here only: --servers renders PNG",
                format.title()
            );
        }
        return render_linear(&a, format);
    }
    if !a.remote.servers.is_empty() {
        return super::distributed::render(&a.opts, &a.output, &a.remote);
    }
    run_traced(
        "render",
        &a.opts,
        &a.output,
        |r, region, tile, sink_file, timing| {
            let sink = PngSink::new(sink_file, region)?;
            let stats = trace_into(&ColourKernel(r), region, tile, &sink, timing)?;
            let t = Instant::now();
            sink.finish()?;
            timing.finish = t.elapsed();
            Ok(stats)
        },
    )
}

/// `raytile render -o x.exr | x.pfm`: the linear colours, kept whole and written at the
/// end (neither format is written in tile order).
fn render_linear(a: &RenderArgs, format: RasterFormat) -> anyhow::Result<ExitCode> {
    run_traced(
        "render",
        &a.opts,
        &a.output,
        |r, region, tile, mut file, timing| {
            let sink = FrameSink::new(region);
            let stats = trace_into(&LinearKernel(r), region, tile, &sink, timing)?;
            let t = Instant::now();
            let px = sink.into_pixels().context("a worker panicked")?;
            let img = LinearImage::from_pixels(region.width, region.height, &px);
            let bytes = match format {
                RasterFormat::Pfm => pfm::write(&img),
                _ => exr::write(&img).map_err(anyhow::Error::msg)?,
            };
            std::io::Write::write_all(&mut file, &bytes)?;
            timing.finish = t.elapsed();
            Ok(stats)
        },
    )
}

/// `raytile hits`.
pub fn hits(a: HitsArgs) -> anyhow::Result<ExitCode> {
    let format = match a.format.as_deref().and_then(HitFormat::from_name) {
        Some(f) => f,
        None => HitFormat::from_path(&a.output).with_context(|| {
            format!(
                "cannot tell the format of {}: use .json, .ndjson, .npy or .csv, or --format",
                a.output.display()
            )
        })?,
    };
    run_traced(
        "hits",
        &a.opts,
        &a.output,
        |r, region, tile, file, timing| {
            // NPY rows go straight from the tiles' records to the file, a row a call
            // (vectored, no copy); the text formats are built in pieces and gathered
            // a megabyte a call.
            let out: Box<dyn std::io::Write + Send> = if format == HitFormat::Npy {
                Box::new(file)
            } else {
                Box::new(std::io::BufWriter::with_capacity(1 << 20, file))
            };
            let sink = HitSink::new(r.scene.clone(), format, out, region)?;
            let stats = trace_into(&HitKernel(r), region, tile, &sink, timing)?;
            let t = Instant::now();
            sink.finish()?;
            timing.finish = t.elapsed();
            Ok(stats)
        },
    )
}

#[derive(Default)]
struct Timing {
    trace: Duration,
    sink_thread: Duration,
    finish: Duration,
}

fn run_traced(
    command: &str,
    opts: &TraceOptions,
    output: &Path,
    body: impl FnOnce(
        &Renderer,
        Rect,
        u32,
        OutputFile,
        &mut Timing,
    ) -> anyhow::Result<render::RenderStats>
    + Send,
) -> anyhow::Result<ExitCode> {
    let t0 = Instant::now();
    let scene = Arc::new(load_scene(&opts.scene)?);
    let parse_s = t0.elapsed();
    let region = opts.region_in(&scene)?;
    let pool = {
        let mut b = rayon::ThreadPoolBuilder::new();
        if let Some(n) = opts.threads {
            b = b.num_threads(n.max(1));
        }
        b.build().context("cannot start the worker threads")?
    };
    let t1 = Instant::now();
    let renderer = pool.install(|| Renderer::new(scene.clone()));
    let build_s = t1.elapsed();
    let file = OutputFile::create(output)
        .with_context(|| format!("cannot create {}", output.display()))?;
    let mut timing = Timing::default();
    let result = pool
        .install(|| body(&renderer, region, opts.tile, file.clone(), &mut timing))
        .and_then(|stats| {
            file.commit()?;
            Ok(stats)
        });
    let stats = match result {
        Ok(s) => s,
        Err(e) => {
            let _ = std::fs::remove_file(output);
            return Err(e.context(format!("cannot write {}", output.display())));
        }
    };
    if opts.stats {
        let primary = region.pixels()
            * if command == "render" {
                scene.samples as u64 * scene.samples as u64
            } else {
                1
            };
        let threads = pool.current_num_threads();
        let trace_thread_s = stats.trace_thread_time.as_secs_f64();
        let line = serde_json::json!({
            "command": command,
            "width": region.width,
            "height": region.height,
            "samples": scene.samples,
            "objects": scene.objects.len(),
            "triangles": scene.triangles(),
            "threads": threads,
            "tile": opts.tile,
            "parse_s": parse_s.as_secs_f64(),
            "build_s": build_s.as_secs_f64(),
            "trace_s": timing.trace.as_secs_f64(),
            "trace_thread_s": trace_thread_s,
            "encode_thread_s": timing.sink_thread.as_secs_f64(),
            "finish_s": timing.finish.as_secs_f64(),
            "total_s": t0.elapsed().as_secs_f64(),
            "primary_rays": primary,
            "rays": stats.rays,
            "primary_mrays_per_s": primary as f64 / timing.trace.as_secs_f64() / 1e6,
            "tracing_mrays_per_s": primary as f64 / (trace_thread_s / threads as f64) / 1e6,
        });
        eprintln!("{line}");
    }
    // The process ends with the command, and the operating system takes its memory
    // back at once: dropping a large scene and its world would free their objects one
    // by one first (about 10 ms of a 0.36 s command on 100 k spheres).
    std::mem::forget(renderer);
    std::mem::forget(scene);
    Ok(ExitCode::SUCCESS)
}

/// Runs the tile loop with a progress bar (on a terminal) and sink timing around `sink`.
fn trace_into<K: Kernel, S: TileSink<K::Pixel>>(
    kernel: &K,
    region: Rect,
    tile: u32,
    sink: &S,
    timing: &mut Timing,
) -> anyhow::Result<render::RenderStats> {
    let tiles = sink.tile_shape(region, tile).cut(region).len() as u64;
    let bar = if std::io::stderr().is_terminal() {
        let b = ProgressBar::new(tiles);
        b.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} tiles  {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        Some(b)
    } else {
        None
    };
    let observed = Observed {
        inner: sink,
        bar: bar.as_ref(),
        rays: AtomicU64::new(0),
        sink_nanos: AtomicU64::new(0),
        start: Instant::now(),
    };
    let t = Instant::now();
    let result = render::run(kernel, region, tile, &render::Cancel::new(), &observed);
    timing.trace = t.elapsed();
    timing.sink_thread = Duration::from_nanos(observed.sink_nanos.load(Ordering::Relaxed));
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    Ok(result?)
}

/// Wraps a sink: advances the progress bar and times the sink's own work.
struct Observed<'a, S> {
    inner: &'a S,
    bar: Option<&'a ProgressBar>,
    rays: AtomicU64,
    sink_nanos: AtomicU64,
    start: Instant,
}

impl<T, S: TileSink<T>> TileSink<T> for Observed<'_, S> {
    fn tile_shape(&self, region: Rect, tile_px: u32) -> render::TileShape {
        self.inner.tile_shape(region, tile_px)
    }

    fn tile(&self, tile: Tile<T>) -> Result<(), SinkClosed> {
        let rays = self.rays.fetch_add(tile.rays, Ordering::Relaxed) + tile.rays;
        let t = Instant::now();
        let r = self.inner.tile(tile);
        self.sink_nanos
            .fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
        if let Some(b) = self.bar {
            b.inc(1);
            let secs = self.start.elapsed().as_secs_f64().max(1e-9);
            b.set_message(format!("{:.2} Mrays/s", rays as f64 / secs / 1e6));
        }
        r
    }
}
