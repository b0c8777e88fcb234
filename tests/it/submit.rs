//! `raytile submit` and `raytile scenes`, the grader container's commands, on the real
//! binary: a results file in the asked form whatever happens (the service unreachable,
//! busy past the deadline, refusing), busy answers retried after `Retry-After` with one
//! idempotency key, and, against a real server, whole submissions graded and recorded.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

use super::auth::{ADMIN, Server, create_token, serve};
use super::support::raytile;
use super::support_server;

/// A loopback port that nothing listens on, kept bound (never listening) while the
/// guard lives: a connection to it is refused, and no other test's server can take it
/// meanwhile. (Freed at once, as it once was, a server started by a test running
/// beside this one took it now and then, and the service seemed up.)
struct ClosedPort {
    _held: socket2::Socket,
    port: u16,
}

impl ClosedPort {
    fn url(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }
}

fn closed_port() -> ClosedPort {
    use socket2::{Domain, Socket, Type};
    let held = Socket::new(Domain::IPV4, Type::STREAM, None).expect("a socket");
    let loopback = std::net::SocketAddr::from(([127, 0, 0, 1], 0));
    held.bind(&loopback.into()).expect("a free port");
    let port = held
        .local_addr()
        .ok()
        .and_then(|a| a.as_socket())
        .expect("an address")
        .port();
    ClosedPort { _held: held, port }
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
    let closed = closed_port();
    let server = closed.url();
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

#[test]
fn an_https_server_is_spoken_to_in_tls_and_a_plain_one_behind_it_is_a_results_file() {
    // A plain-HTTP peer at an https:// URL: the client must attempt a TLS handshake
    // (its crypto set up, no panic), fail it, and still write the results file.
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let server = format!("https://{}", listener.local_addr().unwrap());
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut stream) = stream else { return };
            let _ = stream.write_all(b"HTTP/1.1 400 Bad Request\r\nconnection: close\r\n\r\n");
        }
    });
    let dir = tempfile::tempdir().unwrap();
    let sub = some_files(dir.path());
    let out = dir.path().join("results.json");
    let (code, stderr) = submit(&[
        "--server",
        &server,
        "--assignment",
        "a1",
        "--student",
        "s1",
        "--report",
        "gradescope",
        "--deadline",
        "1",
        "-o",
        out.to_str().unwrap(),
        sub.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let r = read_json(&out);
    assert_eq!(r["score"], 0.0);
    assert!(r.to_string().contains(UNREACHABLE), "{r}");
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
fn an_answer_cut_off_is_asked_for_again_under_the_same_key() {
    let dir = tempfile::tempdir().unwrap();
    let sub = some_files(dir.path());
    let cut = "HTTP/1.1 201 Created\r\ncontent-type: application/json\r\ncontent-length: 500\r\nconnection: close\r\n\r\n{\"graded\"".to_owned();
    let (url, log) = fake_peer(vec![
        cut,
        http("200 OK", "", r#"{"score": 1, "scenes": []}"#),
    ]);
    let out = dir.path().join("results.json");
    let (code, stderr) = submit(&[
        "--server",
        &url,
        "--assignment",
        "a1",
        "--student",
        "s1",
        "-o",
        out.to_str().unwrap(),
        sub.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(0), "{stderr}");
    assert_eq!(read_json(&out)["score"], 1);
    let seen = log.lock().unwrap().clone();
    assert_eq!(seen.len(), 2);
    assert_eq!(
        seen[0].header("idempotency-key"),
        seen[1].header("idempotency-key")
    );
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

// ---- Against a real server ----

/// A small scene (16 × 12: grading it is quick) with its sphere moved by `translate`.
fn tiny(translate: [f64; 3]) -> Value {
    json!({"version": 1, "image": {"width": 16, "height": 12}, "camera": {"focal_length": 1},
           "objects": [{"name": "ball", "shape": "sphere", "transform": [{"translate": translate}]}],
           "lights": [{"type": "point", "position": [0, -4, 0], "colour": [1, 0.75, 0.5]}]})
}

/// An assignment of `n` tiny scenes, `s0`…: image, hits and both in turn, every other
/// one hidden; 2 points each.
fn assignment(n: usize) -> Value {
    let grades = ["image", "hits", "both"];
    let scenes: Vec<Value> = (0..n)
        .map(|i| {
            json!({"name": format!("s{i}"), "scene": tiny([0.1 * i as f64 - 0.2, 0.0, 2.0]),
                   "points": 2, "grade": grades[i % 3],
                   "visibility": if i % 2 == 0 { "visible" } else { "hidden" }})
        })
        .collect();
    json!({"version": 1, "title": "Ray casting", "due": "2099-01-01T00:00:00Z", "scenes": scenes})
}

/// A course: a server on a data folder with an instructor's and a grader's token, and
/// an assignment of `n` scenes pushed with `raytile assignment push`.
struct Course {
    dir: tempfile::TempDir,
    server: Server,
    instructor: String,
    grader: String,
    id: String,
}

impl Course {
    fn data(&self) -> PathBuf {
        self.dir.path().join("data")
    }

    fn args<'a>(&'a self, extra: &[&'a str]) -> Vec<&'a str> {
        let mut a = vec![
            "--server",
            self.server.url.as_str(),
            "--assignment",
            self.id.as_str(),
            "--token",
            self.grader.as_str(),
        ];
        a.extend_from_slice(extra);
        a
    }
}

fn start(data: &Path, extra: &[&str]) -> Server {
    let data = data.to_str().unwrap();
    serve(
        &[&["--data-dir", data, "--require-token"], extra].concat(),
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    )
}

fn course(n: usize, server_args: &[&str]) -> Course {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let store = ["--data-dir", data.to_str().unwrap()];
    let id = "ray-casting".to_owned();
    let (instructor, _) = create_token(&[&["--role", "instructor"], &store[..]].concat());
    let (grader, _) =
        create_token(&[&["--role", "grader", "--assignment", &id], &store[..]].concat());
    let server = start(&data, server_args);
    let file = dir.path().join(format!("{id}.json"));
    std::fs::write(&file, serde_json::to_vec(&assignment(n)).unwrap()).unwrap();
    let o = raytile()
        .args([
            "assignment",
            "push",
            file.to_str().unwrap(),
            "--server",
            &server.url,
        ])
        .env("RAYTILE_TOKEN", &instructor)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    Course {
        dir,
        server,
        instructor,
        grader,
        id,
    }
}

/// `raytile scenes` into `DIR/scenes`, then each scene rendered by the binary into
/// `DIR/out` as its grade asks (a correct student's files); the lines it printed.
fn fetch_and_render(c: &Course) -> (PathBuf, Vec<Vec<String>>) {
    let scenes = c.dir.path().join("scenes");
    let out = c.dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let o = raytile()
        .arg("scenes")
        .args(c.args(&["-o", scenes.to_str().unwrap()]))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let lines: Vec<Vec<String>> = String::from_utf8(o.stdout)
        .unwrap()
        .lines()
        .map(|l| l.split('\t').map(str::to_owned).collect())
        .collect();
    for l in &lines {
        let (name, grade, path) = (&l[0], &l[1], &l[2]);
        let mut kinds = vec![];
        if grade != "hits" {
            kinds.push(("render", "png"));
        }
        if grade != "image" {
            kinds.push(("hits", "npy"));
        }
        for (cmd, ext) in kinds {
            let file = out.join(format!("{name}.{ext}"));
            let o = super::support::run(&[cmd, path, "-o", file.to_str().unwrap()]);
            assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        }
    }
    (out, lines)
}

/// Every submission recorded for the assignment, read from the store on the data
/// folder (the server may be running: SQLite in WAL mode lets it).
fn recorded(data: &Path, id: &str) -> Vec<raytile::store::assignments::Submission> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let store = raytile::store::Store::open_dir(data).await.unwrap();
        let all = store.submissions(id, None).await.unwrap();
        store.close().await;
        all
    })
}

#[test]
fn a_course_fetches_its_scenes_renders_them_and_submits_them() {
    let c = course(3, &[]);
    let (out, lines) = fetch_and_render(&c);
    let names: Vec<&str> = lines.iter().map(|l| l[0].as_str()).collect();
    assert_eq!(names, ["s0", "s1", "s2"]);
    assert_eq!(lines[2][1], "both");
    // What `raytile scenes` wrote is what was pushed, and validates.
    for (i, l) in lines.iter().enumerate() {
        let path = Path::new(&l[2]);
        assert_eq!(path, c.dir.path().join(format!("scenes/s{i}.json")));
        assert_eq!(read_json(path), assignment(3)["scenes"][i]["scene"]);
        let o = super::support::run(&["validate", &l[2]]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }

    let results = c.dir.path().join("results");
    let gs = results.join("gradescope.json");
    let (code, stderr) = submit(&c.args(&[
        "--student",
        "ada@example.edu",
        "--report",
        "gradescope",
        "-o",
        gs.to_str().unwrap(),
        out.to_str().unwrap(),
    ]));
    assert_eq!(code, Some(0), "{stderr}");
    let r = read_json(&gs);
    assert_eq!(
        (r["score"].as_f64(), r["max_score"].as_f64()),
        (Some(6.0), Some(6.0)),
        "{r}"
    );
    assert_eq!(r["tests"].as_array().unwrap().len(), 3);
    assert_eq!(r["tests"][1]["visibility"], "hidden");

    // One scene wrong (another scene's image), one missing: PrairieLearn's form.
    let wrong = c.dir.path().join("wrong");
    std::fs::create_dir_all(&wrong).unwrap();
    std::fs::copy(out.join("s2.png"), wrong.join("s0.png")).unwrap();
    let pl = results.join("pl.json");
    let (code, stderr) = submit(&c.args(&[
        "--student",
        "bob@example.edu",
        "--report",
        "prairielearn",
        "-o",
        pl.to_str().unwrap(),
        wrong.to_str().unwrap(),
        &format!("s2={}", out.join("s2.png").display()),
        &format!("s2={}", out.join("s2.npy").display()),
    ]));
    assert_eq!(code, Some(0), "{stderr}");
    let r = read_json(&pl);
    assert_eq!(r["gradable"], true);
    let score = r["score"].as_f64().unwrap();
    assert!((score - 2.0 / 6.0).abs() < 1e-9, "{r}");

    let all = recorded(&c.data(), &c.id);
    let students: Vec<&str> = all.iter().map(|s| s.student.as_str()).collect();
    assert_eq!(students, ["ada@example.edu", "bob@example.edu"]);

    // The recipe's last step: the gradebook, a row per student.
    let csv = results.join("grades.csv");
    let o = raytile()
        .args(["assignment", "grades", &c.id, "--server", &c.server.url])
        .args(["--pick", "best", "-o", csv.to_str().unwrap()])
        .env("RAYTILE_TOKEN", &c.instructor)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = std::fs::read_to_string(&csv).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows[0], "student,score,max_score,submitted,submissions");
    assert!(rows[1].starts_with("ada@example.edu,6,6,"), "{csv}");
    assert!(rows[2].starts_with("bob@example.edu,2,6,"), "{csv}");

    // A grader token for another assignment reads nothing: no scenes, an error.
    let data = c.data();
    let (other, _) = create_token(&[
        "--role",
        "grader",
        "--assignment",
        "other",
        "--data-dir",
        data.to_str().unwrap(),
    ]);
    let o = raytile()
        .args(["scenes", "--server", &c.server.url, "--assignment", &c.id])
        .args([
            "--token",
            &other,
            "-o",
            c.dir.path().join("nope").to_str().unwrap(),
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("403"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!c.dir.path().join("nope").exists());
}

/// The multipart form of a submission of every file in `dir` for `student`.
fn form(files: &[(String, String, Vec<u8>)], student: &str) -> reqwest::multipart::Form {
    let mut f = reqwest::multipart::Form::new().text("student", student.to_owned());
    for (scene, file_name, bytes) in files {
        f = f.part(
            scene.clone(),
            reqwest::multipart::Part::bytes(bytes.clone()).file_name(file_name.clone()),
        );
    }
    f
}

fn files_of(dir: &Path) -> Vec<(String, String, Vec<u8>)> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            let stem = p.file_stem().unwrap().to_string_lossy().into_owned();
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (stem, name, std::fs::read(&p).unwrap())
        })
        .collect();
    v.sort();
    v
}

/// One submission posted as `raytile submit` posts it: status, `Retry-After`,
/// `Location`; `None` when no answer came.
async fn post(
    client: &reqwest::Client,
    c_url: &str,
    id: &str,
    token: &str,
    files: &[(String, String, Vec<u8>)],
    student: &str,
    key: &str,
) -> Option<(u16, Option<String>, Option<String>)> {
    let res = client
        .post(format!("{c_url}/v1/assignments/{id}/submissions"))
        .bearer_auth(token)
        .header("idempotency-key", key)
        .multipart(form(files, student))
        .send()
        .await
        .ok()?;
    let h = |n: &str| {
        res.headers()
            .get(n)
            .and_then(|v| v.to_str().ok())
            .map(str::to_owned)
    };
    let (retry, location) = (h("retry-after"), h("location"));
    let status = res.status().as_u16();
    res.bytes().await.ok()?;
    Some((status, retry, location))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_submission_answered_2xx_survives_a_sigkill_once() {
    let c = course(2, &["--submissions-per-hour", "0"]);
    let (out, _) = tokio::task::block_in_place(|| fetch_and_render(&c));
    let files = Arc::new(files_of(&out));
    let client = support_server::client();
    let acked: Arc<Mutex<Vec<(String, String, String)>>> = Arc::default();
    let tried: Arc<Mutex<Vec<(String, String)>>> = Arc::default();
    let url = c.server.url.clone();
    // Eight clients submitting one after another until the server is gone.
    let workers: Vec<_> = (0..8)
        .map(|w| {
            let (client, files, acked, tried) =
                (client.clone(), files.clone(), acked.clone(), tried.clone());
            let (url, id, token) = (url.clone(), c.id.clone(), c.grader.clone());
            tokio::spawn(async move {
                for i in 0..200 {
                    let (student, key) = (format!("w{w}-{i}"), format!("key-w{w}-{i}"));
                    tried.lock().unwrap().push((student.clone(), key.clone()));
                    match post(&client, &url, &id, &token, &files, &student, &key).await {
                        Some((s, _, Some(loc))) if (200..300).contains(&s) => {
                            acked.lock().unwrap().push((student, key, loc))
                        }
                        Some(_) => {}
                        None => return,
                    }
                }
            })
        })
        .collect();
    let t0 = Instant::now();
    while acked.lock().unwrap().len() < 24 {
        assert!(t0.elapsed() < Duration::from_secs(60), "too slow a burst");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let Course {
        dir,
        server,
        instructor,
        grader,
        id,
    } = c;
    // Dropping the server kills it with SIGKILL, mid-burst.
    drop(server);
    for w in workers {
        tokio::time::timeout(Duration::from_secs(60), w)
            .await
            .unwrap()
            .unwrap();
    }
    let acked = acked.lock().unwrap().clone();
    let tried = tried.lock().unwrap().clone();
    assert!(tried.len() > acked.len(), "the kill came after the burst");
    let data = dir.path().join("data");

    // Restarted on the same data, the server lists every acknowledged submission, once.
    let server = tokio::task::block_in_place(|| start(&data, &["--submissions-per-hour", "0"]));
    let listed: Value = client
        .get(format!("{}/v1/assignments/{id}/submissions", server.url))
        .bearer_auth(&instructor)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let listed = listed["submissions"].as_array().expect("a list").clone();
    let count = |student: &str, sid: Option<&str>| {
        listed
            .iter()
            .filter(|s| s["student"] == student)
            .filter(|s| sid.is_none_or(|sid| s["id"] == sid))
            .count()
    };
    for (student, _, loc) in &acked {
        let sid = loc.rsplit('/').next().unwrap();
        assert_eq!(
            count(student, Some(sid)),
            1,
            "{student} ({loc}) answered 2xx is listed"
        );
    }
    for (student, _) in &tried {
        assert!(count(student, None) <= 1, "{student} twice");
    }

    // Every submission of the burst retried with its key: recorded once in the end, the
    // acknowledged ones replayed where they were.
    for (student, key) in &tried {
        let (status, _, loc) = post(&client, &server.url, &id, &grader, &files, student, key)
            .await
            .expect("the restarted server answers");
        match acked.iter().find(|(s, _, _)| s == student) {
            Some((_, _, was)) => {
                assert_eq!(status, 200, "{student}: a replay");
                assert_eq!(loc.as_ref(), Some(was));
            }
            None => assert!(status == 200 || status == 201, "{student}: {status}"),
        }
    }
    let listed = tokio::task::block_in_place(|| recorded(&data, &id));
    assert_eq!(listed.len(), tried.len());
    for (student, _) in &tried {
        assert_eq!(
            listed.iter().filter(|s| &s.student == student).count(),
            1,
            "{student}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hundred_concurrent_submissions_are_answered_and_raytile_submit_records_each_once() {
    // One grading at a time, two waiting: the rest are turned away with 503; three
    // submissions per student an hour: a fourth gets 429.
    let c = course(
        5,
        &[
            "--max-renders",
            "1",
            "--queue",
            "2",
            "--submissions-per-hour",
            "3",
        ],
    );
    let (out, _) = tokio::task::block_in_place(|| fetch_and_render(&c));
    let files = Arc::new(files_of(&out));
    let client = support_server::client();
    let t0 = Instant::now();

    // 100 at once, four for each of 25 students.
    let tasks: Vec<_> = (0..100)
        .map(|i| {
            let (client, files) = (client.clone(), files.clone());
            let (url, id, token) = (c.server.url.clone(), c.id.clone(), c.grader.clone());
            tokio::spawn(async move {
                let student = format!("a-{}", i % 25);
                let answer = post(
                    &client,
                    &url,
                    &id,
                    &token,
                    &files,
                    &student,
                    &format!("ka-{i}"),
                )
                .await;
                (student, answer.expect("an answer"))
            })
        })
        .collect();
    let mut accepted = std::collections::BTreeMap::<String, usize>::new();
    let mut turned_away = std::collections::BTreeMap::<u16, usize>::new();
    for t in tasks {
        let (student, (status, retry, _)) = t.await.unwrap();
        match status {
            200 | 201 => *accepted.entry(student).or_default() += 1,
            429 | 503 => {
                assert!(
                    retry.is_some_and(|r| r.parse::<u64>().is_ok()),
                    "{status} without Retry-After"
                );
                *turned_away.entry(status).or_default() += 1;
            }
            other => panic!("{student}: {other}"),
        }
    }
    assert!(turned_away.values().sum::<usize>() >= 25, "{turned_away:?}");
    eprintln!(
        "100 at once: {} recorded, turned away {turned_away:?}, in {:?}",
        accepted.values().sum::<usize>(),
        t0.elapsed()
    );

    // 100 `raytile submit` at once, a student each: every one recorded, once.
    let results = c.dir.path().join("results");
    let children: Vec<_> = (0..100)
        .map(|i| {
            let o = results.join(format!("b-{i}.json"));
            raytile()
                .arg("submit")
                .args(c.args(&["--student", &format!("b-{i}"), "--deadline", "120"]))
                .args(["-o", o.to_str().unwrap(), out.to_str().unwrap()])
                .stderr(std::process::Stdio::null())
                .spawn()
                .unwrap()
        })
        .collect();
    for (i, mut child) in children.into_iter().enumerate() {
        let status = tokio::task::block_in_place(|| child.wait()).unwrap();
        assert!(status.success(), "b-{i}: {status}");
        let r = read_json(&results.join(format!("b-{i}.json")));
        assert_eq!(r["score"], r["max_score"], "b-{i}: {r}");
    }
    assert!(
        t0.elapsed() < Duration::from_secs(120),
        "{:?}",
        t0.elapsed()
    );

    let listed = tokio::task::block_in_place(|| recorded(&c.data(), &c.id));
    for s in 0..25 {
        let student = format!("a-{s}");
        let n = listed.iter().filter(|r| r.student == student).count();
        assert_eq!(n, accepted.get(&student).copied().unwrap_or(0), "{student}");
        assert!(n <= 3, "{student}: {n}");
    }
    for i in 0..100 {
        let student = format!("b-{i}");
        assert_eq!(
            listed.iter().filter(|r| r.student == student).count(),
            1,
            "{student}"
        );
    }
}

/// A student's `render`: the binary itself, by the output's extension.
fn student_render(dir: &Path) {
    let bin = env!("CARGO_BIN_EXE_raytile");
    let script = format!(
        "#!/bin/sh\ncase \"$2\" in\n  *.png) exec {bin} render \"$1\" -o \"$2\" ;;\n  *) exec {bin} hits \"$1\" -o \"$2\" ;;\nesac\n"
    );
    std::fs::create_dir_all(dir).unwrap();
    let p = dir.join("render");
    std::fs::write(&p, script).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o755)).unwrap();
}

/// `PATH` with the built binary's folder first, as the grader images install it.
fn path_with_raytile() -> String {
    let bin = Path::new(env!("CARGO_BIN_EXE_raytile")).parent().unwrap();
    format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    )
}

fn course_file(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("docs/course")
        .join(path)
}

/// A shipped grader script with its deadlines cut to a second (for a dead service:
/// the flags stay the same).
fn quick_script(dir: &Path, path: &str) -> PathBuf {
    let script = std::fs::read_to_string(course_file(path)).unwrap();
    let quick = script
        .replace("--deadline 300", "--deadline 1")
        .replace("--deadline 180", "--deadline 1")
        .replace("--deadline 60", "--deadline 1");
    assert_ne!(quick, script);
    let p = dir.join("quick.sh");
    std::fs::write(&p, quick).unwrap();
    p
}

/// Runs a grader script with `root` as its platform's folder: exit code, stderr.
fn run_script(
    script: &Path,
    root_var: &str,
    root: &Path,
    env: &[(&str, &str)],
) -> (Option<i32>, String) {
    let o = std::process::Command::new("bash")
        .arg(script)
        .env(root_var, root)
        .env("PATH", path_with_raytile())
        .env_remove("RAYTILE_TOKEN")
        .envs(env.iter().copied())
        .output()
        .unwrap();
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

#[test]
fn the_shipped_gradescope_autograder_grades_a_submission_and_survives_a_dead_service() {
    let c = course(3, &[]);
    let root = c.dir.path().join("autograder");
    student_render(&root.join("submission"));
    std::fs::create_dir_all(root.join("source")).unwrap();
    std::fs::write(
        root.join("submission_metadata.json"),
        r#"{"users": [{"email": "ada@example.edu", "name": "Ada", "id": "1"}]}"#,
    )
    .unwrap();
    let env_file = |server: &str| {
        std::fs::write(
            root.join("source/course.env"),
            format!(
                "RAYTILE_SERVER={server}\nRAYTILE_TOKEN={}\nRAYTILE_ASSIGNMENT={}\n",
                c.grader, c.id
            ),
        )
        .unwrap();
    };
    env_file(&c.server.url);
    let script = course_file("gradescope/run_autograder");
    let (code, stderr) = run_script(&script, "AUTOGRADER_ROOT", &root, &[]);
    assert_eq!(code, Some(0), "{stderr}");
    let results = root.join("results/results.json");
    let r = read_json(&results);
    assert_eq!(
        (r["score"].as_f64(), r["max_score"].as_f64()),
        (Some(6.0), Some(6.0)),
        "{r}"
    );
    let listed = recorded(&c.data(), &c.id);
    assert_eq!(listed.len(), 1);
    assert_eq!(listed[0].student, "ada@example.edu");

    // The service down: still a results file, score 0, "resubmit".
    let closed = closed_port();
    env_file(&closed.url());
    let quick = quick_script(c.dir.path(), "gradescope/run_autograder");
    let (code, stderr) = run_script(&quick, "AUTOGRADER_ROOT", &root, &[]);
    assert_eq!(code, Some(1), "{stderr}");
    let r = read_json(&results);
    assert_eq!(r["score"], 0.0);
    assert!(r["output"].as_str().unwrap().contains(UNREACHABLE), "{r}");
}

#[test]
fn the_shipped_prairielearn_grader_grades_a_submission_and_survives_a_dead_service() {
    let info = read_json(&course_file("prairielearn/info.json"));
    let opts = &info["externalGradingOptions"];
    assert_eq!(opts["enabled"], true);
    assert_eq!(info["gradingMethod"], "External");
    // The entrypoint is the shipped grader, served from serverFilesCourse/raytile/.
    assert_eq!(
        opts["entrypoint"],
        "/grade/serverFilesCourse/raytile/grader.sh"
    );
    assert_eq!(opts["serverFilesCourse"], json!(["raytile/"]));
    let env = &opts["environment"];
    for k in ["RAYTILE_SERVER", "RAYTILE_TOKEN", "RAYTILE_ASSIGNMENT"] {
        assert!(env[k].is_string(), "{k}");
    }
    assert!(
        opts["timeout"].as_u64().unwrap() > 200 + 60,
        "the grader's deadlines fit"
    );

    let c = course(3, &[]);
    let root = c.dir.path().join("grade");
    student_render(&root.join("student"));
    let script = course_file("prairielearn/grader.sh");
    let settings = [
        ("RAYTILE_SERVER", c.server.url.as_str()),
        ("RAYTILE_TOKEN", c.grader.as_str()),
        ("RAYTILE_ASSIGNMENT", c.id.as_str()),
    ];
    let (code, stderr) = run_script(&script, "PL_GRADE_ROOT", &root, &settings);
    assert_eq!(code, Some(0), "{stderr}");
    let results = root.join("results/results.json");
    let r = read_json(&results);
    assert_eq!(
        (r["gradable"].as_bool(), r["score"].as_f64()),
        (Some(true), Some(1.0)),
        "{r}"
    );
    assert_eq!(r["tests"][1]["hidden"], true);
    let listed = recorded(&c.data(), &c.id);
    assert_eq!(listed.len(), 1);
    assert!(
        listed[0].student.starts_with("pl-"),
        "{}",
        listed[0].student
    );

    let closed = closed_port();
    let dead = closed.url();
    let quick = quick_script(c.dir.path(), "prairielearn/grader.sh");
    let settings = [settings[1], settings[2], ("RAYTILE_SERVER", dead.as_str())];
    let (code, stderr) = run_script(&quick, "PL_GRADE_ROOT", &root, &settings);
    assert_eq!(code, Some(1), "{stderr}");
    let r = read_json(&results);
    assert_eq!(r["gradable"], false);
    assert!(r["message"].as_str().unwrap().contains(UNREACHABLE), "{r}");
}
