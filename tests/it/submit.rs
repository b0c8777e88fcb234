//! `raytile submit` and `raytile scenes`, the grader container's commands, on the real
//! binary: a results file in the asked form whatever happens (the service unreachable,
//! busy past the deadline, refusing), busy answers retried after `Retry-After` with one
//! idempotency key, and, against a real server, whole submissions graded and recorded.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::support::raytile;

/// A loopback port that nothing listens on.
fn closed_port() -> u16 {
    let l = TcpListener::bind("127.0.0.1:0").expect("a free port");
    let port = l.local_addr().expect("an address").port();
    drop(l);
    port
}

/// `raytile submit` with these arguments: exit code, standard error.
fn submit(args: &[&str]) -> (Option<i32>, String) {
    let o = raytile()
        .arg("submit")
        .args(args)
        .env_remove("RAYTILE_TOKEN")
        .output()
        .expect("the binary runs");
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

fn read_json(p: &Path) -> Value {
    let bytes = std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
    serde_json::from_slice(&bytes).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A folder with a submission's files (their content does not matter to these tests).
fn some_files(dir: &Path) -> PathBuf {
    let sub = dir.join("sub");
    std::fs::create_dir_all(&sub).unwrap();
    std::fs::write(sub.join("spheres.png"), b"not really a PNG").unwrap();
    std::fs::write(sub.join("secret.npy"), b"not really NPY").unwrap();
    sub
}

const UNREACHABLE: &str = "the grading service could not be reached, resubmit";

#[test]
fn an_unreachable_service_still_gets_a_results_file_in_every_form() {
    let dir = tempfile::tempdir().unwrap();
    let sub = some_files(dir.path());
    let server = format!("http://127.0.0.1:{}", closed_port());
    for form in ["gradescope", "prairielearn", "json", "text"] {
        let out = dir.path().join(format!("results/{form}.json"));
        let t0 = Instant::now();
        let (code, stderr) = submit(&[
            "--server",
            &server,
            "--assignment",
            "a1",
            "--student",
            "s1",
            "--report",
            form,
            "--deadline",
            "1",
            "-o",
            out.to_str().unwrap(),
            sub.to_str().unwrap(),
        ]);
        assert_eq!(code, Some(1), "{form}: {stderr}");
        // Retried until the deadline, and no longer.
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "{form}: {:?}",
            t0.elapsed()
        );
        let text = std::fs::read_to_string(&out).unwrap();
        assert!(text.contains(UNREACHABLE), "{form}: {text}");
        assert!(text.contains("cannot connect"), "{form}: {text}");
        match form {
            "gradescope" => {
                let r = read_json(&out);
                assert_eq!(r["score"], 0.0);
                assert_eq!(r["tests"][0]["status"], "failed");
            }
            "prairielearn" => assert_eq!(read_json(&out)["gradable"], false),
            "json" => assert_eq!(read_json(&out)["graded"], false),
            _ => assert!(text.starts_with("Not graded: "), "{text}"),
        }
    }
}

/// What a fake peer saw of one request.
#[derive(Debug, Clone)]
struct Seen {
    request_line: String,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
}

impl Seen {
    fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
}

/// A loopback HTTP/1.1 peer answering each request with the next of `answers` (the
/// last one repeated), one request per connection; what it saw is kept.
fn fake_peer(answers: Vec<String>) -> (String, Arc<Mutex<Vec<Seen>>>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let seen = Arc::new(Mutex::new(Vec::new()));
    let log = seen.clone();
    std::thread::spawn(move || {
        for (i, stream) in listener.incoming().enumerate() {
            let Ok(mut stream) = stream else { return };
            let mut reader = BufReader::new(stream.try_clone().unwrap());
            let mut request_line = String::new();
            if reader.read_line(&mut request_line).is_err() {
                continue;
            }
            let mut headers = Vec::new();
            loop {
                let mut line = String::new();
                if reader.read_line(&mut line).unwrap_or(0) == 0 || line.trim().is_empty() {
                    break;
                }
                if let Some((k, v)) = line.trim_end().split_once(':') {
                    headers.push((k.trim().to_owned(), v.trim().to_owned()));
                }
            }
            let length = headers
                .iter()
                .find(|(k, _)| k.eq_ignore_ascii_case("content-length"))
                .and_then(|(_, v)| v.parse::<usize>().ok())
                .unwrap_or(0);
            let mut body = vec![0u8; length];
            let _ = reader.read_exact(&mut body);
            log.lock().unwrap().push(Seen {
                request_line: request_line.trim_end().to_owned(),
                headers,
                body,
            });
            let answer = &answers[i.min(answers.len() - 1)];
            let _ = stream.write_all(answer.as_bytes());
        }
    });
    (url, seen)
}

fn http(status: &str, extra: &str, body: &str) -> String {
    format!(
        "HTTP/1.1 {status}\r\ncontent-type: application/json\r\ncontent-length: {}\r\nconnection: close\r\n{extra}\r\n{body}",
        body.len()
    )
}

#[test]
fn busy_answers_are_retried_after_retry_after_with_one_idempotency_key() {
    let dir = tempfile::tempdir().unwrap();
    let sub = some_files(dir.path());
    let busy =
        r#"{"type": "https://raytile.example/problems/busy", "title": "busy", "status": 503}"#;
    let (url, log) = fake_peer(vec![
        http("503 Service Unavailable", "retry-after: 1\r\n", busy),
        http("429 Too Many Requests", "retry-after: 1\r\n", busy),
        http(
            "201 Created",
            "",
            r#"{"score": 8, "max_score": 8, "tests": []}"#,
        ),
    ]);
    let out = dir.path().join("results.json");
    let t0 = Instant::now();
    let (code, stderr) = submit(&[
        "--server",
        &url,
        "--assignment",
        "ray-casting",
        "--student",
        "s 1",
        "--token",
        "rt_secret",
        "--report",
        "gradescope",
        "-o",
        out.to_str().unwrap(),
        sub.to_str().unwrap(),
        &format!("walls={}", sub.join("spheres.png").display()),
    ]);
    assert_eq!(code, Some(0), "{stderr}");
    // Two pauses of at least the second each asked for.
    assert!(t0.elapsed() >= Duration::from_secs(2), "{:?}", t0.elapsed());
    assert_eq!(read_json(&out)["score"], 8);
    let seen = log.lock().unwrap().clone();
    assert_eq!(seen.len(), 3, "{seen:?}");
    let key = seen[0].header("idempotency-key").expect("a key").to_owned();
    assert!(key.len() >= 32, "{key}");
    for s in &seen {
        assert_eq!(
            s.request_line,
            "POST /v1/assignments/ray-casting/submissions?report=gradescope HTTP/1.1"
        );
        assert_eq!(s.header("idempotency-key"), Some(key.as_str()));
        assert_eq!(s.header("authorization"), Some("Bearer rt_secret"));
        let body = String::from_utf8_lossy(&s.body);
        for part in [
            "name=\"student\"\r\n\r\ns 1\r\n",
            "name=\"spheres\"; filename=\"spheres.png\"",
            "name=\"secret\"; filename=\"secret.npy\"",
            "name=\"walls\"; filename=\"spheres.png\"",
            "not really NPY",
        ] {
            assert!(body.contains(part), "{part} in {body}");
        }
    }

    // A second run is another submission: another key.
    let (code, _) = submit(&[
        "--server",
        &url,
        "--assignment",
        "ray-casting",
        "--student",
        "s1",
        "-o",
        out.to_str().unwrap(),
        sub.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(0));
    let seen = log.lock().unwrap().clone();
    assert_ne!(seen[3].header("idempotency-key"), Some(key.as_str()));
    assert_eq!(seen[3].header("authorization"), None);
}

#[test]
fn a_refusal_is_not_retried_and_says_why_and_a_busy_service_past_the_deadline_is_unreachable() {
    let dir = tempfile::tempdir().unwrap();
    let sub = some_files(dir.path());
    let forbidden = r#"{"type": "https://raytile.example/problems/forbidden", "title": "Forbidden", "status": 403, "detail": "this token is not for the assignment a2"}"#;
    let (url, seen) = fake_peer(vec![http("403 Forbidden", "", forbidden)]);
    let out = dir.path().join("pl/results.json");
    let args = |url: &str| {
        vec![
            "--server".to_owned(),
            url.to_owned(),
            "--assignment".into(),
            "a2".into(),
            "--student".into(),
            "s1".into(),
            "--report".into(),
            "prairielearn".into(),
            "--deadline".into(),
            "2".into(),
            "-o".into(),
            out.to_str().unwrap().into(),
            sub.to_str().unwrap().into(),
        ]
    };
    let a = args(&url);
    let (code, stderr) = submit(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, Some(1), "{stderr}");
    assert_eq!(seen.lock().unwrap().len(), 1);
    let r = read_json(&out);
    assert_eq!(r["gradable"], false);
    let message = r["message"].as_str().unwrap();
    assert!(
        message.contains("this token is not for the assignment a2"),
        "{message}"
    );
    assert!(!message.contains(UNREACHABLE), "{message}");

    // Asked to come back after the deadline: given up at once, as unreachable.
    let (url, seen) = fake_peer(vec![http(
        "503 Service Unavailable",
        "retry-after: 30\r\n",
        r#"{"title": "busy"}"#,
    )]);
    let a = args(&url);
    let t0 = Instant::now();
    let (code, _) = submit(&a.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(code, Some(1));
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    assert_eq!(seen.lock().unwrap().len(), 1);
    let message = read_json(&out)["message"].as_str().unwrap().to_owned();
    assert!(
        message.contains(UNREACHABLE) && message.contains("503"),
        "{message}"
    );
}
