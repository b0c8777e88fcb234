//! Helpers for the server tests: a [`TestApp`] that runs the real router on an ephemeral
//! port of 127.0.0.1, in this process, with its own metrics; [`spawn_binary`], the real
//! `raytile serve` as a child process; a reqwest client with generous timeouts so that
//! no test can hang; and scene generators.

#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::Stdio;
use std::time::{Duration, Instant};

use raytile::config::ServeArgs;
use raytile::server::{self, AppState};
use serde_json::{Value, json};
use tokio::net::TcpListener;
use tokio::sync::oneshot;

/// Longest any single request of a test may take before it fails instead of hanging.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(120);

/// A server on `127.0.0.1:<random port>` and a client for it. Dropping it starts the
/// server's graceful shutdown.
pub struct TestApp {
    /// Where it listens.
    pub addr: SocketAddr,
    /// `http://127.0.0.1:<port>`.
    pub url: String,
    /// A client with [`REQUEST_TIMEOUT`].
    pub client: reqwest::Client,
    /// The server's state (metrics, admission).
    pub state: AppState,
    stop: Option<oneshot::Sender<()>>,
    /// The server task; finishes after `stop`.
    pub task: Option<tokio::task::JoinHandle<anyhow::Result<()>>>,
}

/// Test defaults: two trace threads and two render slots whatever the machine, so
/// that the tests behave the same everywhere.
pub fn config() -> ServeArgs {
    ServeArgs {
        addr: "127.0.0.1:0".parse().expect("an address"),
        threads: Some(2),
        max_renders: Some(2),
        ..ServeArgs::default()
    }
}

impl TestApp {
    /// Starts the app with the test defaults.
    pub async fn spawn() -> TestApp {
        TestApp::with(config()).await
    }

    /// Starts the app with `config` (its `addr` is ignored: port 0 on loopback).
    pub async fn with(config: ServeArgs) -> TestApp {
        let listener = TcpListener::bind("127.0.0.1:0")
            .await
            .expect("a free port on loopback");
        let addr = listener.local_addr().expect("a bound address");
        let state = AppState::new(config).expect("the app state");
        let (stop, stopped) = oneshot::channel::<()>();
        let task = tokio::spawn(server::run(listener, state.clone(), async move {
            let _ = stopped.await;
        }));
        TestApp {
            addr,
            url: format!("http://{addr}"),
            client: client(),
            state,
            stop: Some(stop),
            task: Some(task),
        }
    }

    /// `url` + `path`.
    pub fn at(&self, path: &str) -> String {
        format!("{}{path}", self.url)
    }

    /// Starts the graceful shutdown (as SIGTERM would).
    pub fn signal_shutdown(&mut self) {
        if let Some(s) = self.stop.take() {
            let _ = s.send(());
        }
    }

    /// POSTs `body` as JSON to `path` with extra headers.
    pub async fn post_json(
        &self,
        path: &str,
        body: impl Into<reqwest::Body>,
        headers: &[(&str, &str)],
    ) -> reqwest::Response {
        let mut req = self
            .client
            .post(self.at(path))
            .header("content-type", "application/json")
            .body(body);
        for (k, v) in headers {
            req = req.header(*k, *v);
        }
        req.send().await.expect("the server answers")
    }

    /// POSTs a scene document to `path`.
    pub async fn post_scene(&self, path: &str, scene: &Value) -> reqwest::Response {
        self.post_json(path, serde_json::to_vec(scene).expect("JSON"), &[])
            .await
    }

    /// GETs `path`.
    pub async fn get(&self, path: &str) -> reqwest::Response {
        self.client
            .get(self.at(path))
            .send()
            .await
            .expect("the server answers")
    }

    /// The value of an unlabelled metric (a counter or gauge) from `/metrics`.
    pub async fn metric(&self, name: &str) -> f64 {
        let text = self
            .get("/metrics")
            .await
            .text()
            .await
            .expect("metrics text");
        metric_value(&text, name).unwrap_or_else(|| panic!("no metric {name} in:\n{text}"))
    }

    /// The value of an unlabelled metric read from the state, not over HTTP (for
    /// after the server has stopped listening).
    pub fn metric_after_stop(&self, name: &str) -> f64 {
        let text = String::from_utf8(self.state.metrics.encode().expect("metrics"))
            .expect("UTF-8 metrics");
        metric_value(&text, name).unwrap_or_else(|| panic!("no metric {name}"))
    }

    /// Waits (polling, at most `limit`) until `cond` holds of `name`'s value.
    pub async fn wait_for_metric(
        &self,
        name: &str,
        limit: Duration,
        cond: impl Fn(f64) -> bool,
    ) -> f64 {
        let start = std::time::Instant::now();
        loop {
            let v = self.metric(name).await;
            if cond(v) {
                return v;
            }
            assert!(
                start.elapsed() < limit,
                "{name} = {v} did not reach the condition within {limit:?}"
            );
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
}

impl Drop for TestApp {
    fn drop(&mut self) {
        self.signal_shutdown();
    }
}

/// Spawns `raytile serve` (the built binary) on a free port of 127.0.0.1 and returns it
/// with its address (`127.0.0.1:<port>`); its standard output keeps being read into the
/// returned channel.
pub fn spawn_binary(
    args: &[&str],
) -> (
    std::process::Child,
    String,
    std::sync::mpsc::Receiver<String>,
) {
    spawn_binary_env(args, &[])
}

/// [`spawn_binary`] with these environment variables set too.
pub fn spawn_binary_env(
    args: &[&str],
    env: &[(&str, &str)],
) -> (
    std::process::Child,
    String,
    std::sync::mpsc::Receiver<String>,
) {
    let mut child = crate::support::raytile()
        .args(["serve", "--addr", "127.0.0.1:0"])
        .args(args)
        .envs(env.iter().copied())
        .env("RUST_LOG", "info")
        .env("RAYTILE_LOG_FORMAT", "text")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("raytile serve starts");
    let stdout = child.stdout.take().unwrap();
    let (tx, lines) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let addr = loop {
        let line = lines
            .recv_timeout(Duration::from_secs(60))
            .expect("the server logs its address");
        if let Some(i) = line.find("listening on http://") {
            let rest = &line[i + "listening on http://".len()..];
            break rest.split_whitespace().next().unwrap().to_owned();
        }
    };
    (child, addr, lines)
}

/// Waits at most `limit` for `child` to exit; kills it and fails the test past that.
pub fn wait_exit(child: &mut std::process::Child, limit: Duration) -> std::process::ExitStatus {
    let start = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("the server did not exit within {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A client with [`REQUEST_TIMEOUT`] and no connection reuse surprises.
pub fn client() -> reqwest::Client {
    raytile::cli::remote::client_builder()
        .timeout(REQUEST_TIMEOUT)
        .connect_timeout(Duration::from_secs(10))
        .build()
        .expect("a client")
}

/// Finds `name value` (no labels) or `name{...} value` (first match) in Prometheus text.
pub fn metric_value(text: &str, name: &str) -> Option<f64> {
    text.lines().filter(|l| !l.starts_with('#')).find_map(|l| {
        let rest = l.strip_prefix(name)?;
        let value = if rest.starts_with(' ') {
            rest
        } else if rest.starts_with('{') {
            &rest[rest.find('}')? + 1..]
        } else {
            return None;
        };
        value.trim().parse().ok()
    })
}

/// Reads a shipped scene as JSON.
pub fn shipped(name: &str) -> Value {
    let text = std::fs::read_to_string(crate::support::scene(name)).expect("a shipped scene");
    serde_json::from_str(&text).expect("JSON")
}

/// A `width × height` scene of `n × n` spheres in a grid on a floor, lit by one point
/// light: cheap per ray, busy enough that its PNG does not compress to nothing.
pub fn sphere_grid(width: u32, height: u32, n: u32, samples: u32) -> Value {
    let mut objects = vec![json!({ "shape": "plane", "material": "floor" })];
    for i in 0..n {
        for j in 0..n {
            let x = (i as f64 - n as f64 / 2.0) * 0.5;
            let z = 2.0 + j as f64 * 0.5;
            let hue = [(i % 3) as f64 / 2.0, (j % 4) as f64 / 3.0, 0.6];
            objects.push(json!({
                "shape": "sphere",
                "material": { "diffuse": hue, "specular": [0.3, 0.3, 0.3], "shininess": 20 },
                "transform": [ { "scale": 0.2 }, { "translate": [x, 0.2, z] } ]
            }));
        }
    }
    json!({
        "version": 1,
        "image": { "width": width, "height": height, "samples": samples },
        "camera": { "look_at": { "eye": [0, 2.5, -2], "target": [0, 0, 4], "up": [0, 1, 0] } },
        "background": [0.1, 0.1, 0.2],
        "ambient": [0.1, 0.1, 0.1],
        "materials": { "floor": { "diffuse": [0.5, 0.5, 0.5] } },
        "objects": objects,
        "lights": [ { "type": "point", "position": [-3, 6, 0], "colour": [1, 1, 1] } ]
    })
}

/// `scene` with its image size changed.
pub fn resized(mut scene: Value, width: u32, height: u32) -> Value {
    scene["image"]["width"] = json!(width);
    scene["image"]["height"] = json!(height);
    scene
}

/// Reads a response body chunk by chunk until `enough` bytes arrived or it ends.
pub async fn read_at_least(res: &mut reqwest::Response, enough: usize) -> Vec<u8> {
    let mut got = Vec::new();
    while got.len() < enough {
        match res.chunk().await.expect("a body chunk") {
            Some(c) => got.extend_from_slice(&c),
            None => break,
        }
    }
    got
}

/// Checks a problem document: media type, `type` URI, `title`, `status`, `detail`.
pub async fn problem(res: reqwest::Response, status: u16, slug: &str) -> Value {
    assert_eq!(res.status().as_u16(), status, "status");
    let ct = res
        .headers()
        .get("content-type")
        .and_then(|v| v.to_str().ok())
        .unwrap_or_default()
        .to_owned();
    assert_eq!(ct, "application/problem+json");
    let doc: Value = res.json().await.expect("a JSON problem");
    assert_eq!(
        doc["type"],
        format!("https://raytile.example/problems/{slug}"),
        "{doc}"
    );
    assert!(doc["title"].is_string(), "{doc}");
    assert_eq!(doc["status"], status, "{doc}");
    assert!(doc["detail"].is_string(), "{doc}");
    doc
}
