//! raytile deployed as it runs, on loopback: two `raytile serve` processes (the real
//! binary) behind nginx configured from `deploy/nginx-test.conf.template`, and
//! `raytile render --servers` spreading one frame over the replicas while one of them
//! dies. Everything listens on 127.0.0.1, every wait is bounded, and every child process
//! is killed when a test ends, passed or failed.
//!
//! The nginx test is ignored by a plain `cargo test`, since a fresh machine with only the
//! Rust toolchain has no nginx; `bash .ci/test-all` installs nginx and runs it with every
//! other test. Run without nginx, it fails and says how to install it.

use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc::Receiver;
use std::time::{Duration, Instant};

use futures::StreamExt;
use serde_json::Value;

use crate::support::{raytile, scene_file};
use crate::support_server::{resized, shipped, spawn_binary, sphere_grid};

/// Longest any one HTTP request of these tests may take.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(60);
/// Longest any `raytile render` of these tests may take.
const RENDER_LIMIT: Duration = Duration::from_secs(180);

/// The child processes of a test, killed and reaped when dropped: also when an
/// assertion fails halfway, so no server outlives its test.
#[derive(Default)]
struct Children {
    procs: Vec<(String, Child)>,
    /// The replicas' log lines: kept so that their readers keep draining the pipes.
    logs: Vec<Receiver<String>>,
}

impl Children {
    /// Starts a replica (`raytile serve` on a free loopback port); its `host:port`.
    fn replica(&mut self, name: &str) -> String {
        let (child, addr, lines) =
            spawn_binary(&["--threads", "1", "--max-renders", "2", "--queue", "64"]);
        self.procs.push((name.to_owned(), child));
        self.logs.push(lines);
        addr
    }

    /// Kills the child called `name` at once (SIGKILL: no graceful drain) and reaps it.
    fn kill(&mut self, name: &str) {
        for (n, child) in &mut self.procs {
            if n == name {
                let _ = child.kill();
                let _ = child.wait();
            }
        }
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        for (_, child) in &mut self.procs {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

/// The nginx binary, from `PATH` or where Debian puts it (`/usr/sbin`, often not on a
/// user's `PATH`).
fn nginx_binary() -> PathBuf {
    let path = std::env::var_os("PATH").unwrap_or_default();
    std::env::split_paths(&path)
        .chain(["/usr/sbin", "/usr/local/sbin", "/usr/local/nginx/sbin"].map(PathBuf::from))
        .map(|dir| dir.join("nginx"))
        .find(|p| p.is_file())
        .unwrap_or_else(|| {
            panic!(
                "nginx is not installed, and these tests run raytile behind it: install it \
                 (Debian or Ubuntu: `apt-get install nginx`; .ci/run does this)"
            )
        })
}

/// A port that was free a moment ago on 127.0.0.1.
fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free loopback port")
        .port()
}

fn port_of(addr: &str) -> &str {
    addr.rsplit(':').next().expect("host:port")
}

/// Starts nginx from the test template in `dir`, in front of the replicas at
/// `upstream_a` and `upstream_b` (`host:port`), and waits until it accepts connections;
/// its address.
fn start_nginx(children: &mut Children, dir: &Path, upstream_a: &str, upstream_b: &str) -> String {
    let template = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/nginx-test.conf.template"),
    )
    .expect("the nginx test template");
    let port = free_port();
    let conf = template
        .replace("@PREFIX@", &dir.display().to_string())
        .replace("@LISTEN_PORT@", &port.to_string())
        .replace("@UPSTREAM_A@", port_of(upstream_a))
        .replace("@UPSTREAM_B@", port_of(upstream_b));
    let conf_path = dir.join("nginx.conf");
    std::fs::write(&conf_path, conf).expect("a writable temp dir");
    let stderr_path = dir.join("nginx.stderr");
    let stderr = std::fs::File::create(&stderr_path).expect("a writable temp dir");
    let child = Command::new(nginx_binary())
        .arg("-p")
        .arg(dir)
        .arg("-c")
        .arg(&conf_path)
        .args(["-e", "stderr"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(stderr)
        .spawn()
        .expect("nginx starts");
    children.procs.push(("nginx".into(), child));
    let addr = format!("127.0.0.1:{port}");
    let start = Instant::now();
    while TcpStream::connect(&addr).is_err() {
        let exited = children
            .procs
            .last_mut()
            .and_then(|(_, c)| c.try_wait().ok().flatten());
        if exited.is_some() || start.elapsed() > Duration::from_secs(20) {
            panic!(
                "nginx did not start listening on {addr}:\n{}",
                std::fs::read_to_string(&stderr_path).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    addr
}

/// A client that goes straight to loopback, whatever proxy the environment names.
fn client() -> reqwest::Client {
    raytile::cli::remote::client_builder()
        .no_proxy()
        .timeout(REQUEST_TIMEOUT)
        .connect_timeout(Duration::from_secs(5))
        .build()
        .expect("a client")
}

/// Successful renders a replica has answered, from its `/metrics`.
async fn renders_served(client: &reqwest::Client, addr: &str) -> u64 {
    let text = client
        .get(format!("http://{addr}/metrics"))
        .send()
        .await
        .expect("the replica answers")
        .text()
        .await
        .expect("metrics text");
    text.lines()
        .filter(|l| {
            l.starts_with("raytile_http_requests_total{")
                && l.contains("route=\"/v1/render\"")
                && l.contains("status=\"200\"")
        })
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum::<f64>() as u64
}

/// `raytile render SCENE -o OUT [args]` as a child process, standard error to a file,
/// with no proxy in between.
fn spawn_render(scene: &Path, out: &Path, stderr: &Path, args: &[&str]) -> Child {
    raytile()
        .arg("render")
        .arg(scene)
        .arg("-o")
        .arg(out)
        .args(args)
        .env("NO_PROXY", "*")
        .env_remove("HTTP_PROXY")
        .env_remove("http_proxy")
        .env_remove("ALL_PROXY")
        .env_remove("all_proxy")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(stderr).expect("a writable temp dir"))
        .spawn()
        .expect("raytile render starts")
}

/// Waits (at most [`RENDER_LIMIT`]) for a render; its exit code and standard error.
fn finish_render(mut child: Child, stderr: &Path) -> (Option<i32>, String) {
    let start = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().expect("waitable") {
            break s;
        }
        if start.elapsed() > RENDER_LIMIT {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "raytile render took more than {RENDER_LIMIT:?}:\n{}",
                std::fs::read_to_string(stderr).unwrap_or_default()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    (
        status.code(),
        std::fs::read_to_string(stderr).unwrap_or_default(),
    )
}

/// The `--stats` line of a render's standard error.
fn stats(stderr: &str) -> Value {
    let line = stderr
        .lines()
        .rfind(|l| l.starts_with('{'))
        .unwrap_or_else(|| panic!("no --stats line in:\n{stderr}"));
    serde_json::from_str(line).expect("a JSON stats line")
}

/// A local `raytile render` of `scene`: the bytes every other path must reproduce.
fn local_render(scene: &Path, dir: &Path) -> Vec<u8> {
    let out = dir.join("local.png");
    let status = raytile()
        .arg("render")
        .arg(scene)
        .arg("-o")
        .arg(&out)
        .status()
        .expect("raytile render runs");
    assert!(status.success(), "the local render fails");
    std::fs::read(out).expect("the local render's output")
}

#[test]
#[ignore = "needs nginx: `bash .ci/test-all` installs it and runs every test"]
fn a_hundred_renders_through_nginx_all_succeed_on_both_replicas() {
    let mut children = Children::default();
    let dir = tempfile::tempdir().expect("a temp dir");
    let a = children.replica("a");
    let b = children.replica("b");
    let lb = start_nginx(&mut children, dir.path(), &a, &b);

    // Four small scenes, each with the bytes a local render gives.
    let scenes: Vec<(Vec<u8>, Vec<u8>)> = ["sphere.json", "cube.json", "cone.json", "mesh.json"]
        .iter()
        .map(|name| {
            let path = scene_file(&dir, name, &resized(shipped(name), 40, 30));
            let body = std::fs::read(&path).expect("the scene file");
            (body, local_render(&path, dir.path()))
        })
        .collect();

    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("a runtime");
    rt.block_on(async {
        let client = client();
        let url = format!("http://{lb}/v1/render");
        // At most eight at a time: well inside the replicas' slots and queues, so that
        // every one succeeds on its first replica.
        let results: Vec<(usize, u16, bytes::Bytes)> = futures::stream::iter(0..100)
            .map(|i| {
                let (body, _) = &scenes[i % scenes.len()];
                let req = client
                    .post(&url)
                    .header("content-type", "application/json")
                    .body(body.clone());
                async move {
                    let res = req.send().await.expect("nginx answers");
                    let status = res.status().as_u16();
                    (i, status, res.bytes().await.expect("a whole body"))
                }
            })
            .buffer_unordered(8)
            .collect()
            .await;
        assert_eq!(results.len(), 100);
        for (i, status, body) in &results {
            assert_eq!(
                *status,
                200,
                "request {i}: {}",
                String::from_utf8_lossy(body)
            );
            assert!(
                body[..] == scenes[i % scenes.len()].1[..],
                "request {i}: not the local render's bytes"
            );
        }
        let (on_a, on_b) = (
            renders_served(&client, &a).await,
            renders_served(&client, &b).await,
        );
        assert!(on_a > 0 && on_b > 0, "a served {on_a}, b served {on_b}");
        assert_eq!(on_a + on_b, 100, "a served {on_a}, b served {on_b}");
    });
}

#[test]
fn servers_finish_the_frame_when_a_replica_dies() {
    let mut children = Children::default();
    let dir = tempfile::tempdir().expect("a temp dir");
    let a = children.replica("a");
    let b = children.replica("b");
    // Bands slow enough on one thread that replica a is still tracing its first one
    // when it is killed.
    let scene = scene_file(&dir, "grid.json", &sphere_grid(320, 256, 8, 4));
    let expected = local_render(&scene, dir.path());
    let servers = format!("http://{a},http://{b}");

    // 1. Replica a dies (SIGKILL) while it streams its first band.
    let out = dir.path().join("killed.png");
    let err = dir.path().join("killed.stderr");
    let render = spawn_render(
        &scene,
        &out,
        &err,
        &[
            "--servers",
            &servers,
            "--bands-per-server",
            "4",
            "--per-server",
            "1",
            "--stats",
        ],
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("a runtime");
    let client = client();
    let start = Instant::now();
    while rt.block_on(renders_served(&client, &a)) == 0 {
        assert!(
            start.elapsed() < Duration::from_secs(60),
            "replica a never started a band"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    children.kill("a");
    let mut render = render;
    assert!(
        render.try_wait().expect("waitable").is_none(),
        "the render finished before replica a was killed: make its bands slower"
    );
    let (code, stderr) = finish_render(render, &err);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(
        std::fs::read(&out).expect("the output") == expected,
        "not the local render's bytes"
    );
    let s = stats(&stderr);
    assert!(s["retries"].as_u64() >= Some(1), "{stderr}");
    // 256 rows for 2 × 4 bands: 32 rows each, one 32-pixel tile high.
    assert_eq!(s["bands"], 8, "{stderr}");
    let by_server = |i: usize| s["bands_by_server"][i].as_u64().unwrap_or_default();
    assert_eq!(by_server(0) + by_server(1), 8, "{stderr}");
    assert!(stderr.contains(&format!("http://{a}")), "{stderr}");

    // 2. Replica a is dead from the start: b renders the frame alone.
    let out = dir.path().join("dead.png");
    let err = dir.path().join("dead.stderr");
    let render = spawn_render(&scene, &out, &err, &["--servers", &servers, "--stats"]);
    let (code, stderr) = finish_render(render, &err);
    assert_eq!(code, Some(0), "{stderr}");
    assert!(
        std::fs::read(&out).expect("the output") == expected,
        "not the local render's bytes"
    );
    assert!(stderr.contains("cannot connect"), "{stderr}");
    assert_eq!(stats(&stderr)["bands_by_server"][0], 0, "{stderr}");

    // 3. Only dead servers: a bounded number of tries, then one line that names the
    // band and the server, and no output file.
    let out = dir.path().join("none.png");
    let err = dir.path().join("none.stderr");
    let render = spawn_render(
        &scene,
        &out,
        &err,
        &["--servers", &format!("http://{a}"), "--attempts", "2"],
    );
    let (code, stderr) = finish_render(render, &err);
    assert_eq!(code, Some(2), "{stderr}");
    let last = stderr.lines().last().unwrap_or_default();
    assert!(
        last.starts_with("raytile: region 0,")
            && last.contains("failed 2 times")
            && last.contains(&format!("http://{a}")),
        "{stderr}"
    );
    assert!(!out.exists(), "a failed render leaves no file");

    // 4. A bad scene is refused before any request leaves.
    let bad = scene_file(
        &dir,
        "bad.json",
        &serde_json::json!({ "version": 1, "image": { "width": 0, "height": 8 } }),
    );
    let render = spawn_render(&bad, &out, &err, &["--servers", &format!("http://{a}")]);
    let (code, stderr) = finish_render(render, &err);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("/image/width"), "{stderr}");
    assert!(!stderr.contains("cannot connect"), "{stderr}");
}
