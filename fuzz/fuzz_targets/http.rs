//! The server's request handling, in process, through the real router: query strings
//! of the routes that take them, and the grade request's envelope as JSON and as
//! multipart. Answers must be a status below 500 (503 aside) and a whole body.
#![no_main]

use std::sync::OnceLock;

use axum::body::Body;
use axum::http::{Method, Request};
use libfuzzer_sys::fuzz_target;
use raytile::config::ServeArgs;
use raytile::server::{AppState, app};
use tower::ServiceExt;

/// A 5 × 5 scene: cheap enough to render on every input that reaches the renderer.
const SCENE: &str = r#"{"version":1,"image":{"width":5,"height":5},
"camera":{"focal_length":1},"objects":[{"shape":"sphere","transform":[{"translate":[0,0,4]}]}],
"lights":[{"type":"point","position":[0,-2,0]}]}"#;

fn runtime() -> &'static (tokio::runtime::Runtime, AppState) {
    static RT: OnceLock<(tokio::runtime::Runtime, AppState)> = OnceLock::new();
    RT.get_or_init(|| {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("a runtime");
        let config = ServeArgs {
            threads: Some(1),
            max_renders: Some(1),
            max_pixels: 4096,
            max_samples: 2,
            deadline_seconds: 5.0,
            ..ServeArgs::default()
        };
        let state = AppState::new(config).expect("the app state");
        (rt, state)
    })
}

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let text = String::from_utf8_lossy(rest);
    let (path, content_type, body): (String, &str, Vec<u8>) = match pick % 6 {
        0 => ("/v1/grade".into(), "application/json", rest.to_vec()),
        1 => (
            "/v1/grade".into(),
            "multipart/form-data; boundary=XyZ",
            rest.to_vec(),
        ),
        2 => (format!("/v1/render?{text}"), "application/json", SCENE.into()),
        3 => (format!("/v1/hits?{text}"), "application/json", SCENE.into()),
        4 => (format!("/v1/trace?{text}"), "application/json", SCENE.into()),
        _ => (format!("/v1/grade?{text}"), "application/json", rest.to_vec()),
    };
    let Ok(req) = Request::builder()
        .method(Method::POST)
        .uri(path)
        .header("content-type", content_type)
        .body(Body::from(body))
    else {
        // Not a URI a client could send.
        return;
    };
    let (rt, state) = runtime();
    rt.block_on(async {
        let res = app(state.clone())
            .oneshot(req)
            .await
            .expect("the router is infallible");
        let status = res.status();
        assert!(
            !status.is_server_error() || status.as_u16() == 503,
            "answered {status}"
        );
        let _ = axum::body::to_bytes(res.into_body(), 64 << 20).await;
    });
});
