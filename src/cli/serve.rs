//! `raytile serve` (also what `raytile` with no command does) and `raytile healthcheck`,
//! the probe the container image runs: it has no shell and no curl.

use std::net::SocketAddr;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;

use crate::config::ServeArgs;

/// `raytile healthcheck`.
#[derive(Debug, clap::Args)]
pub struct HealthcheckArgs {
    /// The URL to probe [default: `/healthz` on 127.0.0.1 at `RAYTILE_ADDR`'s port,
    /// else `http://127.0.0.1:8080/healthz`].
    #[arg(long)]
    pub url: Option<String>,
    /// Give up after this many seconds.
    #[arg(long, default_value_t = 3)]
    pub timeout_seconds: u64,
}

/// Runs the server on a multi-threaded tokio runtime until it has shut down.
pub fn serve(args: ServeArgs) -> anyhow::Result<ExitCode> {
    crate::server::observe::init_logging(args.log_format == "json");
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .thread_name("raytile-io")
        .build()
        .context("cannot start the async runtime")?;
    runtime.block_on(crate::server::serve(args))?;
    Ok(ExitCode::SUCCESS)
}

/// The URL probed when none is given.
pub fn default_health_url(raytile_addr: Option<&str>) -> String {
    let port = raytile_addr
        .and_then(|a| a.trim().parse::<SocketAddr>().ok())
        .map_or(8080, |a| a.port());
    format!("http://127.0.0.1:{port}/healthz")
}

/// Exits 0 when the URL answers 200, 1 otherwise (saying why on standard error).
pub fn healthcheck(args: HealthcheckArgs) -> anyhow::Result<ExitCode> {
    let url = args
        .url
        .unwrap_or_else(|| default_health_url(std::env::var("RAYTILE_ADDR").ok().as_deref()));
    let probe = async {
        let client = super::remote::client_builder()
            .timeout(Duration::from_secs(args.timeout_seconds.max(1)))
            .build()?;
        let res = client.get(&url).send().await?;
        Ok::<_, reqwest::Error>(res.status())
    };
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    match runtime.block_on(probe) {
        Ok(s) if s == reqwest::StatusCode::OK => Ok(ExitCode::SUCCESS),
        Ok(s) => {
            eprintln!("raytile healthcheck: {url} answered {s}");
            Ok(ExitCode::from(1))
        }
        Err(e) => {
            eprintln!("raytile healthcheck: {url}: {e}");
            Ok(ExitCode::from(1))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_url_follows_raytile_addr() {
        assert_eq!(
            default_health_url(Some("0.0.0.0:9000")),
            "http://127.0.0.1:9000/healthz"
        );
        assert_eq!(
            default_health_url(Some("[::]:8081")),
            "http://127.0.0.1:8081/healthz"
        );
        assert_eq!(default_health_url(None), "http://127.0.0.1:8080/healthz");
        assert_eq!(
            default_health_url(Some("nonsense")),
            "http://127.0.0.1:8080/healthz"
        );
    }
}
