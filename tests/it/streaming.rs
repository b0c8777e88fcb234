//! Streamed answers whatever the frame's shape, and clients that do not read: chunks
//! of at most 64 KiB and a bounded server whatever the width; renders whose clients
//! are behind park (no slot, no thread) and do not delay others; a parked render
//! resumes with exactly the bytes of the command line, or is stopped after
//! `--stall-seconds`.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use raytile::config::ServeArgs;
use serde_json::Value;

use crate::support::{raytile, scene_file};
use crate::support_server::{
    TestApp, config, metric_value, resized, shipped, spawn_binary, sphere_grid,
};

/// The largest chunk the server may send.
const CHUNK_BYTES: usize = 64 * 1024;

/// Sends `POST path` with `scene` on a fresh connection and reads nothing.
fn send(addr: &str, path: &str, scene: &Value, accept: &str) -> TcpStream {
    let body = serde_json::to_vec(scene).unwrap();
    let mut s = TcpStream::connect(addr).expect("a connection");
    let head = format!(
        "POST {path} HTTP/1.1\r\nhost: {addr}\r\ncontent-type: application/json\r\n\
         accept: {accept}\r\ncontent-length: {}\r\nconnection: close\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).unwrap();
    s.write_all(&body).unwrap();
    s
}

/// What a raw HTTP/1.1 answer held: its status, the size of each chunk of its chunked
/// body, the body, and whether it ended with the last (empty) chunk.
struct Answer {
    status: u16,
    chunks: Vec<usize>,
    body: Vec<u8>,
    complete: bool,
}

/// Reads a chunked answer to its end (or to the connection's end).
fn read_answer(mut s: TcpStream) -> Answer {
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    let mut raw = Vec::new();
    // A cut connection ends in a reset or an EOF: what arrived until then counts.
    let _ = s.read_to_end(&mut raw);
    let end = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a complete head");
    let head = String::from_utf8_lossy(&raw[..end]).to_string();
    let status = head[9..12].parse().unwrap();
    assert!(
        head.to_ascii_lowercase()
            .contains("transfer-encoding: chunked"),
        "{head}"
    );
    let mut rest = &raw[end + 4..];
    let (mut chunks, mut body, mut complete) = (Vec::new(), Vec::new(), false);
    while let Some(nl) = rest.windows(2).position(|w| w == b"\r\n") {
        let size_text = String::from_utf8_lossy(&rest[..nl]).to_string();
        let size = usize::from_str_radix(size_text.split(';').next().unwrap().trim(), 16)
            .unwrap_or_else(|_| panic!("a chunk size, not {size_text:?}"));
        rest = &rest[nl + 2..];
        if size == 0 {
            complete = true;
            break;
        }
        if rest.len() < size + 2 {
            break;
        }
        chunks.push(size);
        body.extend_from_slice(&rest[..size]);
        rest = &rest[size + 2..];
    }
    Answer {
        status,
        chunks,
        body,
        complete,
    }
}

/// The peak resident memory of process `pid` in bytes (`VmHWM`).
fn peak_rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let line = status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .expect("VmHWM");
    let kb: u64 = line.split_whitespace().nth(1).unwrap().parse().unwrap();
    kb * 1024
}

/// `command` (`hits`, `render`) of `scene` by the command line, into a file `out_name`.
fn cli_output(command: &str, scene: &Value, out_name: &str) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let input = scene_file(&dir, "scene.json", scene);
    let out = dir.path().join(out_name);
    let status = raytile()
        .arg(command)
        .arg(&input)
        .arg("-o")
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    std::fs::read(out).unwrap()
}

/// Waits (at most `limit`) until `/metrics` holds `needle`.
async fn wait_for_text(app: &TestApp, needle: &str, limit: Duration) {
    let start = Instant::now();
    loop {
        let text = app.get("/metrics").await.text().await.unwrap();
        if text.contains(needle) {
            return;
        }
        assert!(start.elapsed() < limit, "no {needle} in:\n{text}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[test]
fn a_four_million_pixel_row_streams_in_small_chunks_from_a_small_server() {
    let (mut child, addr, _log) = spawn_binary(&["--max-renders", "2", "--threads", "2"]);
    let scene = resized(shipped("lecture.json"), 4_000_000, 1);
    for accept in ["application/json", "application/x-npy"] {
        let answer = read_answer(send(&addr, "/v1/hits", &scene, accept));
        assert_eq!(answer.status, 200);
        assert!(answer.complete, "{accept}: the body was cut");
        let largest = answer.chunks.iter().max().copied().unwrap_or(0);
        assert!(
            largest <= CHUNK_BYTES,
            "{accept}: a chunk of {largest} bytes"
        );
        if accept == "application/json" {
            assert!(answer.body.starts_with(b"{\"width\":4000000,\"height\":1,"));
            assert!(answer.body.ends_with(b"]}\n"));
            assert!(answer.body.len() > 400_000_000, "{}", answer.body.len());
        } else {
            // 99 bytes a record after the header.
            assert!(answer.body.len() >= 4_000_000 * 99);
        }
    }
    let peak = peak_rss(child.id());
    let _ = child.kill();
    let _ = child.wait();
    // It used to take 1.9 GB: one chunk held a whole row of records, twice.
    assert!(peak < 300 << 20, "the server peaked at {} MiB", peak >> 20);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn ten_clients_that_never_read_do_not_delay_a_small_render() {
    let app = TestApp::with(ServeArgs {
        stall_seconds: 120.0,
        ..config()
    })
    .await;
    let addr = app.addr.to_string();
    let large = sphere_grid(4096, 4096, 10, 1);
    let stalled: Vec<TcpStream> = (0..10)
        .map(|_| send(&addr, "/v1/hits", &large, "application/json"))
        .collect();
    // Each traces until its client is behind, then parks and lets the next in: soon
    // all ten are parked, none waits for a slot and none holds one.
    let start = Instant::now();
    loop {
        let text = app.get("/metrics").await.text().await.unwrap();
        let value = |name| metric_value(&text, name).unwrap_or(-1.0);
        if value("raytile_renders_parked") == 10.0
            && value("raytile_queue_depth") == 0.0
            && value("raytile_renders_in_flight") == 0.0
        {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the stalled renders still hold the slots:\n{text}"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let small = resized(shipped("sphere.json"), 64, 64);
    let expected = cli_output("render", &small, "s.png");
    let t = Instant::now();
    let res = app.post_scene("/v1/render", &small).await;
    assert_eq!(res.status(), 200);
    let png = res.bytes().await.unwrap();
    let took = t.elapsed();
    assert!(png == expected, "the small render's bytes differ");
    assert!(
        took < Duration::from_secs(3),
        "the small render took {took:?}"
    );
    drop(stalled);
}

/// Renders parked, renders in flight and rays traced, from one reading of the metrics.
async fn parked_state(app: &TestApp) -> (f64, f64, f64) {
    let text = app.get("/metrics").await.text().await.unwrap();
    let value = |name| metric_value(&text, name).unwrap_or(-1.0);
    (
        value("raytile_renders_parked"),
        value("raytile_renders_in_flight"),
        value("raytile_rays_traced_total"),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_parked_render_resumes_when_its_client_reads_with_the_exact_bytes() {
    let app = TestApp::with(ServeArgs {
        stall_seconds: 60.0,
        ..config()
    })
    .await;
    let scene = sphere_grid(640, 480, 4, 1);
    let expected = cli_output("hits", &scene, "h.json");
    let stream = send(
        &app.addr.to_string(),
        "/v1/hits",
        &scene,
        "application/json",
    );
    app.wait_for_metric("raytile_renders_parked", Duration::from_secs(60), |v| {
        v == 1.0
    })
    .await;
    // Parked: no slot held, nothing traced. The kernel may still take some bytes of
    // the answer and so let the render trace a little more before it parks again;
    // what must come is a parked spell that lasts, each look one reading of the
    // metrics (one per metric raced with such a resumption).
    let start = Instant::now();
    loop {
        let before = parked_state(&app).await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        let after = parked_state(&app).await;
        if before.0 == 1.0 && before.1 == 0.0 && after == before {
            break;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the parked render holds a slot or keeps tracing: \
             (parked, in flight, rays) {before:?} then {after:?}"
        );
    }
    let answer = tokio::task::spawn_blocking(move || read_answer(stream))
        .await
        .unwrap();
    assert_eq!(answer.status, 200);
    assert!(answer.complete);
    assert!(answer.chunks.iter().all(|&c| c <= CHUNK_BYTES));
    assert!(answer.body == expected, "the resumed render's bytes differ");
    assert_eq!(app.metric("raytile_renders_parked").await, 0.0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_parked_render_past_stall_seconds_is_stopped_and_its_slot_freed() {
    let app = TestApp::with(ServeArgs {
        stall_seconds: 0.5,
        max_renders: Some(1),
        ..config()
    })
    .await;
    let stream = send(
        &app.addr.to_string(),
        "/v1/hits",
        &sphere_grid(4096, 4096, 10, 1),
        "application/json",
    );
    app.wait_for_metric("raytile_renders_parked", Duration::from_secs(60), |v| {
        v == 1.0
    })
    .await;
    wait_for_text(
        &app,
        "raytile_render_duration_seconds_count{outcome=\"cancelled\",output=\"json\"} 1",
        Duration::from_secs(30),
    )
    .await;
    assert_eq!(app.metric("raytile_renders_parked").await, 0.0);
    assert_eq!(app.metric("raytile_renders_in_flight").await, 0.0);
    // The one slot is free for the next render.
    let res = app
        .post_scene("/v1/render", &sphere_grid(64, 48, 2, 1))
        .await;
    assert_eq!(res.status(), 200);
    assert!(!res.bytes().await.unwrap().is_empty());
    // The stopped answer is cut, never a short body that looks whole.
    let answer = tokio::task::spawn_blocking(move || read_answer(stream))
        .await
        .unwrap();
    assert_eq!(answer.status, 200);
    assert!(!answer.complete);
}
