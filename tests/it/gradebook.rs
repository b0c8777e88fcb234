//! The instructor's read side on the real binary: `raytile assignment push` puts an
//! assignment (a refused one printed with its pointers), students' submissions are
//! recorded through `POST …/submissions`, and `GET …/submissions`, `GET …/grades.csv`
//! (latest or best, also through `raytile assignment grades`) and `GET …/stats` show
//! them to an instructor and to nobody else. Every answer is checked against
//! `api/openapi.yaml`. On SQLite in a temporary data folder, and on PostgreSQL when
//! `RAYTILE_TEST_DATABASE_URL` names one (`bash .ci/test-all` sets it up).

use std::process::Output;

use serde_json::{Value, json};

use crate::assignments_http::{
    Submit, assignment, authed, black_png, entry, fresh, get, json_of, render_png, small, submit,
};
use crate::auth::{ADMIN, create_token, serve};
use crate::openapi::{Answer, check, document};
use crate::support::{decode_png, encode_png, raytile};
use crate::support_server::{client, problem};

/// A file part of a submission: the scene, the file's name, its bytes.
type Part<'a> = (&'a str, &'a str, Vec<u8>);

/// An id with a comma and quotes: the CSV must quote it, and give it back as it was.
const ODD_STUDENT: &str = "o'neil, \"bo\"";

/// `raytile` with `args`, `RAYTILE_TOKEN` set to `token` (or unset).
fn cli(args: &[&str], token: Option<&str>) -> Output {
    let mut cmd = raytile();
    cmd.args(args).env_remove("RAYTILE_TOKEN");
    if let Some(t) = token {
        cmd.env("RAYTILE_TOKEN", t);
    }
    cmd.output().expect("the raytile binary runs")
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// `GET path` as `token`, checked against the document as `template`.
async fn read(url: &str, path: &str, template: &str, token: Option<&str>) -> Answer {
    let answer = Answer::from_reqwest(get(url, path, token).await).await;
    check(&document(), "get", template, &answer);
    answer
}

fn csv_rows(body: &[u8]) -> Vec<Vec<String>> {
    let mut r = csv::Reader::from_reader(body);
    let header: Vec<String> = r
        .headers()
        .expect("a header")
        .iter()
        .map(str::to_owned)
        .collect();
    assert_eq!(
        header,
        ["student", "score", "max_score", "submitted", "submissions"]
    );
    r.records()
        .map(|rec| rec.expect("a row").iter().map(str::to_owned).collect())
        .collect()
}

/// `png` upside down: what a tracer with y pointing up makes.
fn flipped(png: &[u8]) -> Vec<u8> {
    let (w, h, rgb) = decode_png(png);
    let rows: Vec<&[u8]> = rgb.chunks(w as usize * 3).rev().collect();
    encode_png(w, h, &rows.concat())
}

/// The score as the gradebook writes it (at most four decimals).
fn short(x: &Value) -> String {
    raytile::grade::score::short(x.as_f64().expect("a number"))
}

/// The whole flow on the store that `store` names (`--data-dir D` or `--database URL`).
async fn gradebook_flow(store: &[&str]) {
    let id = fresh("gb");
    let (instructor, _) = create_token(&[&["--role", "instructor"], store].concat());
    let (grader, _) = create_token(&[&["--role", "grader", "--assignment", &id], store].concat());
    let server = serve(
        &[&["--require-token", "--submissions-per-hour", "0"], store].concat(),
        &[("RAYTILE_ADMIN_TOKEN", ADMIN)],
    );
    let url = server.url.as_str();
    let files = tempfile::tempdir().expect("a temp dir");
    let file = files.path().join("ray-casting.json");

    // Pushed from the command line: the revision alone on stdout.
    // The visible scene is not symmetric top to bottom, so that an image upside down
    // fails and is diagnosed.
    let (spheres, secret) = (small("showcase.json"), small("sphere.json"));
    let doc = assignment(
        "Ray casting",
        vec![
            entry("spheres", spheres.clone(), "image", "visible"),
            entry("secret", secret.clone(), "image", "hidden"),
        ],
    );
    std::fs::write(&file, doc.to_string()).expect("writable");
    let push = |token: Option<&str>| {
        let path = file.to_str().expect("UTF-8");
        cli(
            &["assignment", "push", path, "--server", url, "--id", &id],
            token,
        )
    };
    let out = push(Some(&instructor));
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(String::from_utf8_lossy(&out.stdout), "1\n");
    assert!(stderr(&out).contains("created"), "{}", stderr(&out));
    let out = push(Some(&instructor));
    assert_eq!(String::from_utf8_lossy(&out.stdout), "2\n");
    assert!(stderr(&out).contains("replaced"), "{}", stderr(&out));

    // Refused: exit 1, the server's problem on stderr, each problem at its pointer.
    for (token, expected) in [(None, "Unauthorized"), (Some(grader.as_str()), "Forbidden")] {
        let out = push(token);
        assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
        assert!(stderr(&out).contains(expected), "{}", stderr(&out));
        assert!(out.stdout.is_empty());
    }
    let mut bad = doc.clone();
    bad["scenes"][0]["points"] = json!(-1);
    bad["scenes"][1]["colour"] = json!("red");
    let bad_file = files.path().join("bad.json");
    std::fs::write(&bad_file, bad.to_string()).expect("writable");
    let out = cli(
        &[
            "assignment",
            "push",
            bad_file.to_str().expect("UTF-8"),
            "--server",
            url,
        ],
        Some(&instructor),
    );
    assert_eq!(out.status.code(), Some(1), "{}", stderr(&out));
    let said = stderr(&out);
    assert!(said.contains("Invalid assignment"), "{said}");
    assert!(said.contains("\n  /scenes/0/points: "), "{said}");
    assert!(said.contains("\n  /scenes/1/colour: "), "{said}");
    // Pushed under its stem, `bad`, it never was.
    assert_eq!(
        read(
            url,
            "/v1/assignments/bad/stats",
            "/v1/assignments/{id}/stats",
            Some(&instructor)
        )
        .await
        .status,
        404
    );

    // Four submissions from three students.
    let (right_spheres, right_secret, black) = (
        render_png(url, &spheres).await,
        render_png(url, &secret).await,
        black_png(),
    );
    let sent: [(&str, Vec<Part>); 5] = [
        (
            "amy",
            vec![
                ("spheres", "spheres.png", right_spheres.clone()),
                ("secret", "secret.png", black.clone()),
            ],
        ),
        (
            "bob",
            vec![
                ("spheres", "spheres.png", right_spheres.clone()),
                ("secret", "secret.png", right_secret.clone()),
            ],
        ),
        (
            "amy",
            vec![
                ("spheres", "spheres.png", black.clone()),
                ("secret", "secret.png", black.clone()),
            ],
        ),
        (ODD_STUDENT, vec![("spheres", "spheres.png", black.clone())]),
        (
            "bob",
            vec![
                ("spheres", "spheres.png", flipped(&right_spheres)),
                ("secret", "secret.png", right_secret.clone()),
            ],
        ),
    ];
    let mut locations = Vec::new();
    for (student, files) in sent {
        let (answer, location, _) = submit(
            url,
            &id,
            &grader,
            Submit {
                student,
                files,
                report: None,
                key: None,
            },
        )
        .await;
        assert_eq!(
            answer.status,
            201,
            "{}",
            String::from_utf8_lossy(&answer.body)
        );
        locations.push(location.expect("a recorded submission's Location"));
    }

    // The listing: every submission oldest first, each scene's outcome, the result.
    let subs_path = format!("/v1/assignments/{id}/submissions");
    let subs_t = "/v1/assignments/{id}/submissions";
    let listing = read(url, &subs_path, subs_t, Some(&instructor)).await;
    assert_eq!(listing.status, 200);
    let all = json_of(&listing)["submissions"].clone();
    let all = all.as_array().expect("a list");
    let students: Vec<&str> = all.iter().map(|s| s["student"].as_str().unwrap()).collect();
    assert_eq!(students, ["amy", "bob", "amy", ODD_STUDENT, "bob"]);
    let statuses = |s: &Value| -> Vec<String> {
        s["scenes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| {
                format!(
                    "{}={}",
                    x["name"].as_str().unwrap(),
                    x["status"].as_str().unwrap()
                )
            })
            .collect()
    };
    assert_eq!(statuses(&all[0]), ["spheres=passed", "secret=failed"]);
    assert_eq!(statuses(&all[1]), ["spheres=passed", "secret=passed"]);
    assert_eq!(statuses(&all[3]), ["spheres=failed", "secret=missing"]);
    assert_eq!(statuses(&all[4]), ["spheres=failed", "secret=passed"]);
    assert_eq!(all[4]["scenes"][0]["diagnosis"][0], "flipped_vertically");
    assert!(
        all.iter()
            .all(|s| s["revision"] == 2 && s["max_score"] == 10.0)
    );
    assert_eq!(all[1]["score"], 10.0);
    // Each recorded submission's Location answers it, as the listing shows it.
    let one_t = "/v1/assignments/{id}/submissions/{submission}";
    for (i, loc) in locations.iter().enumerate() {
        let one = read(url, loc, one_t, Some(&instructor)).await;
        assert_eq!(one.status, 200, "{loc}");
        assert_eq!(json_of(&one), all[i], "{loc}");
    }
    assert_eq!(
        read(url, &locations[0], one_t, Some(&grader)).await.status,
        403
    );
    assert_eq!(read(url, &locations[0], one_t, None).await.status, 401);
    let unknown = format!("{subs_path}/0123abcd");
    assert_eq!(
        read(url, &unknown, one_t, Some(&instructor)).await.status,
        404
    );
    assert_eq!(all[0]["result"]["scenes"][0]["status"], "passed");
    // The hidden scene's stored result shows the instructor no more than the student.
    assert!(
        all[0]["result"]["scenes"][1]["parts"][0]
            .get("report")
            .is_none()
    );
    let amy = read(
        url,
        &format!("{subs_path}?student=amy"),
        subs_t,
        Some(&instructor),
    )
    .await;
    let amy = json_of(&amy)["submissions"].clone();
    assert_eq!(amy.as_array().unwrap().len(), 2);
    assert_eq!(
        (&amy[0]["id"], &amy[1]["id"]),
        (&all[0]["id"], &all[2]["id"])
    );
    // amy's first (right spheres) beats her second (all black).
    assert!(all[0]["score"].as_f64() > all[2]["score"].as_f64());

    // The gradebook: one row per student, sorted; the latest or the best.
    let grades_t = "/v1/assignments/{id}/grades.csv";
    let grades_path = format!("/v1/assignments/{id}/grades.csv");
    let latest = read(url, &grades_path, grades_t, Some(&instructor)).await;
    assert_eq!(latest.status, 200);
    let rows = csv_rows(&latest.body);
    let row = |s: &Value, n: &str| {
        vec![
            s["student"].as_str().unwrap().to_owned(),
            short(&s["score"]),
            "10".to_owned(),
            s["submitted"].as_str().unwrap().to_owned(),
            n.to_owned(),
        ]
    };
    assert_eq!(
        rows,
        [row(&all[2], "2"), row(&all[4], "2"), row(&all[3], "1")]
    );
    let best = read(
        url,
        &format!("{grades_path}?pick=best"),
        grades_t,
        Some(&instructor),
    )
    .await;
    assert_eq!(
        csv_rows(&best.body),
        [row(&all[0], "2"), row(&all[1], "2"), row(&all[3], "1")]
    );
    let explicit = read(
        url,
        &format!("{grades_path}?pick=latest"),
        grades_t,
        Some(&instructor),
    )
    .await;
    assert_eq!(explicit.body, latest.body);

    // From the command line, into a new folder: the same bytes.
    let out_file = files.path().join("export/grades.csv");
    let out = cli(
        &[
            "assignment",
            "grades",
            &id,
            "--server",
            url,
            "--pick",
            "best",
            "-o",
            out_file.to_str().expect("UTF-8"),
        ],
        Some(&instructor),
    );
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(std::fs::read(&out_file).expect("written"), best.body);
    assert!(stderr(&out).contains("3 student(s)"), "{}", stderr(&out));
    let out = cli(
        &[
            "assignment",
            "grades",
            &id,
            "--server",
            url,
            "--token",
            &instructor,
        ],
        None,
    );
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(out.stdout, latest.body);

    // The statistics, per scene in the assignment's order.
    let stats_t = "/v1/assignments/{id}/stats";
    let stats_path = format!("/v1/assignments/{id}/stats");
    let stats = read(url, &stats_path, stats_t, Some(&instructor)).await;
    assert_eq!(stats.status, 200);
    let s = json_of(&stats);
    assert_eq!(
        (s["submissions"].as_u64(), s["students"].as_u64()),
        (Some(5), Some(3))
    );
    assert_eq!(
        (s["pick"].as_str(), s["revision"].as_i64()),
        (Some("all"), Some(2))
    );
    assert_eq!(s["last_submitted"], all[4]["submitted"]);
    let (sph, sec) = (&s["scenes"][0], &s["scenes"][1]);
    assert_eq!(
        (sph["name"].as_str(), sec["name"].as_str()),
        (Some("spheres"), Some("secret"))
    );
    assert_eq!(
        sph["statuses"],
        json!({"passed": 2, "failed": 3, "missing": 0, "ungradable": 0})
    );
    assert_eq!(sph["pass_rate"], 0.4);
    assert_eq!(sph["max_points"], 5.0);
    let mean: f64 = all
        .iter()
        .map(|x| x["scenes"][0]["points"].as_f64().unwrap())
        .sum::<f64>()
        / 5.0;
    assert!((sph["mean_points"].as_f64().unwrap() - mean).abs() < 1e-9);
    assert_eq!(
        sec["statuses"],
        json!({"passed": 2, "failed": 2, "missing": 1, "ungradable": 0})
    );
    // The upside-down image's mistake is named; the black ones match none. The hidden
    // scene's feedback was never shown, so it names no mistakes.
    assert_eq!(
        sph["diagnoses"][0],
        json!({"name": "flipped_vertically", "count": 1})
    );
    assert_eq!(sec["diagnoses"], json!([]));
    let latest_stats = read(
        url,
        &format!("{stats_path}?pick=latest"),
        stats_t,
        Some(&instructor),
    )
    .await;
    let l = json_of(&latest_stats);
    assert_eq!(
        (l["submissions"].as_u64(), l["pick"].as_str()),
        (Some(3), Some("latest"))
    );
    // Of the latest, bob's upside-down one replaces his right one.
    assert_eq!(l["scenes"][0]["statuses"]["passed"], 0);
    assert_eq!(l["scenes"][1]["statuses"]["passed"], 1);

    // Nobody but an instructor: 401 without a token, 403 for the assignment's grader.
    for (path, template) in [
        (&subs_path, subs_t),
        (&grades_path, grades_t),
        (&stats_path, stats_t),
    ] {
        let res = get(url, path, None).await;
        assert_eq!(
            res.headers()
                .get("www-authenticate")
                .and_then(|v| v.to_str().ok()),
            Some("Bearer"),
            "{path}"
        );
        problem(res, 401, "unauthorized").await;
        let answer = read(url, path, template, None).await;
        assert_eq!(answer.status, 401);
        let answer = read(url, path, template, Some(&grader)).await;
        assert_eq!(answer.status, 403, "{path}");
        // A bad query, and an id no assignment has.
        let answer = read(
            url,
            &format!("{path}?pick=worst&student=x"),
            template,
            Some(ADMIN),
        )
        .await;
        assert_eq!(answer.status, 400, "{path}");
        let other = path.replace(&id, "no-such-assignment");
        let answer = read(url, &other, template, Some(&instructor)).await;
        assert_eq!(answer.status, 404, "{other}");
    }
    let out = cli(
        &["assignment", "grades", &id, "--server", url],
        Some(&grader),
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(stderr(&out).contains("Forbidden"), "{}", stderr(&out));
    let out = cli(
        &[
            "assignment",
            "grades",
            &id,
            "--server",
            "http://127.0.0.1:9",
        ],
        Some(&instructor),
    );
    assert_eq!(out.status.code(), Some(2), "{}", stderr(&out));
    assert!(stderr(&out).contains("cannot reach"), "{}", stderr(&out));

    // Deleted, the assignment is unknown to the gradebook too.
    let res = authed(
        client().delete(format!("{url}/v1/assignments/{id}")),
        Some(&instructor),
    )
    .send()
    .await
    .expect("an answer");
    assert_eq!(res.status().as_u16(), 204);
    let answer = read(url, &grades_path, grades_t, Some(&instructor)).await;
    assert_eq!(answer.status, 404);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn instructors_read_submissions_grades_and_statistics_on_sqlite() {
    let dir = tempfile::tempdir().expect("a temp dir");
    let data = dir.path().join("data");
    gradebook_flow(&["--data-dir", data.to_str().expect("UTF-8")]).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs PostgreSQL: run .ci/test-all"]
async fn instructors_read_submissions_grades_and_statistics_on_postgres() {
    let url = std::env::var("RAYTILE_TEST_DATABASE_URL")
        .expect("RAYTILE_TEST_DATABASE_URL names a PostgreSQL database");
    gradebook_flow(&["--database", &url]).await;
}
