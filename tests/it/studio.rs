//! The studio (`GET /`) in a real browser: `web/test/studio.test.mjs` drives Debian's
//! chromium with playwright-core against the real router on a loopback port, through
//! every panel (render, trace, validation problems, grading, hit data, cancel). Ignored by
//! a plain `cargo test`, since it needs chromium and `web/node_modules`:
//! `bash .ci/test-all` installs both and runs it. Screenshots of each step land in
//! `studio-shots/` under Cargo's temporary directory for tests (the test prints where).

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
    assert!(stdout.contains("8 passed, 0 failed"), "{stdout}");
}
