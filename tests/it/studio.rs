//! The studio (`GET /`) in a real browser: `web/test/studio.test.mjs` drives Debian's
//! chromium with playwright-core against the real router on a loopback port, through
//! every panel (the page's streaming PNG decoder first; then render, trace and the
//! pixel's rays over the image, validation problems, grading and a worst pixel's trace,
//! the objects, depth and normals views of hit data, a large render drawn band by band
//! and cancelled). Ignored by a plain `cargo test`, since it needs chromium and
//! `web/node_modules`: `bash .ci/test-all` installs both and runs it. Screenshots of each
//! step land in `studio-shots/` under Cargo's temporary directory for tests (the test
//! prints where).
//! The page's route and headers are checked without a browser too.

use std::path::Path;
use std::process::Command;

use crate::support_server::{TestApp, shipped, sphere_grid};

/// The lecture's reference render, flipped top to bottom: the classic mistake of writing
/// rows bottom-up.
async fn flipped_reference(app: &TestApp) -> Vec<u8> {
    let png = app
        .post_scene("/v1/render", &shipped("lecture.json"))
        .await
        .bytes()
        .await
        .expect("the reference render");
    let img = image::load_from_memory(&png).expect("a PNG").flipv();
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("an encoded PNG");
    out.into_inner()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_and_its_assets_are_served_with_the_security_headers() {
    let app = TestApp::spawn().await;
    let page = app.get("/").await;
    assert_eq!(page.status(), 200);
    let h = page.headers().clone();
    assert_eq!(h["content-type"], "text/html; charset=utf-8");
    let csp = h["content-security-policy"].to_str().unwrap();
    assert!(
        csp.contains("default-src 'none'") && csp.contains("connect-src 'self'"),
        "{csp}"
    );
    assert_eq!(h["x-content-type-options"], "nosniff");
    assert_eq!(h["x-frame-options"], "DENY");
    assert!(h.contains_key("x-request-id"));
    // Asked for nothing, it gets the plain page.
    assert!(!h.contains_key("content-encoding"));
    let html = page.text().await.unwrap();
    for id in [
        "scene-editor",
        "example-picker",
        "render-button",
        "render-image",
        "render-status",
        "hits-view",
        "trace-panel",
        "grade-input",
        "grade-result",
        "diff-image",
    ] {
        assert!(html.contains(&format!("data-testid=\"{id}\"")), "{id}");
    }
    assert!(html.contains("/studio/studio.js") && html.contains("/studio/studio.css"));

    let js = app
        .client
        .get(app.at("/studio/studio.js"))
        .header("accept-encoding", "gzip")
        .send()
        .await
        .unwrap();
    assert_eq!(js.status(), 200);
    assert_eq!(js.headers()["content-encoding"], "gzip");
    assert_eq!(
        js.headers()["content-type"],
        "text/javascript; charset=utf-8"
    );
    let gz = js.bytes().await.unwrap();
    assert_eq!(&gz[..2], &[0x1f, 0x8b], "a gzip stream");

    let css = app.get("/studio/studio.css").await;
    assert_eq!(css.headers()["content-type"], "text/css; charset=utf-8");
    assert!(
        css.text()
            .await
            .unwrap()
            .contains("prefers-color-scheme: dark")
    );

    // Anything but GET is refused with a problem document, as for the API.
    let post = app.client.post(app.at("/")).send().await.unwrap();
    assert_eq!(post.status(), 405);
    assert_eq!(post.headers()["content-type"], "application/problem+json");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "needs chromium and web/node_modules: `bash .ci/test-all` installs them and runs every test"]
async fn the_studio_renders_traces_validates_grades_and_cancels_in_a_browser() {
    let app = TestApp::spawn().await;
    let fixtures = tempfile::tempdir().expect("a temp dir");
    let flipped = flipped_reference(&app).await;
    std::fs::write(fixtures.path().join("flipped.png"), flipped).expect("flipped.png");
    // Many seconds of tracing on two threads: still going when the page cancels it.
    let big = serde_json::to_vec_pretty(&sphere_grid(4096, 4096, 10, 2)).expect("JSON");
    std::fs::write(fixtures.path().join("big.json"), big).expect("big.json");

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let shots = Path::new(env!("CARGO_TARGET_TMPDIR")).join("studio-shots");
    let (url, dir) = (app.url.clone(), fixtures.path().to_path_buf());
    let output = tokio::task::spawn_blocking(move || {
        Command::new("node")
            .arg(root.join("web/test/studio.test.mjs"))
            .arg(&url)
            .arg(&dir)
            .arg(&shots)
            .output()
    })
    .await
    .expect("the browser test's thread")
    .expect("node runs (is Node.js installed?)");
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    println!("{stdout}");
    eprintln!("{stderr}");
    assert!(
        output.status.success(),
        "the browser test failed:\n{stdout}\n{stderr}"
    );
    assert!(stdout.contains("13 passed, 0 failed"), "{stdout}");
}
