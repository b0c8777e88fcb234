//! `GET /v1/scenes` and `GET /v1/scenes/{name}`: the example scenes of `scenes/`,
//! compiled into the binary so that the service needs no files at run time.
//!
//! `{name}` is the file's stem or its file name: `/v1/scenes/showcase` and
//! `/v1/scenes/showcase.json` are the same document, served byte for byte as shipped.
//!
//! ```json
//! { "scenes": [ { "name": "cone", "href": "/v1/scenes/cone", "width": 320, "height": 240,
//!                 "samples": 1, "objects": 3, "lights": 1 } ] }
//! ```

use std::sync::OnceLock;

use axum::Json;
use axum::Router;
use axum::extract::Path;
use axum::http::{HeaderValue, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use serde::Serialize;

use super::AppState;
use super::error::ApiError;
use crate::scene::{self, Limits};

/// The routes: `GET /v1/scenes`, `GET /v1/scenes/{name}`.
pub fn router() -> Router<AppState> {
    Router::new()
        .route("/v1/scenes", get(list))
        .route("/v1/scenes/{name}", get(one))
}

/// Every file of `scenes/` that is a scene, by stem. A test checks this list against
/// the folder, so a new scene cannot be forgotten here.
pub const SCENES: &[(&str, &str)] = &[
    ("cone", include_str!("../../scenes/cone.json")),
    ("cube", include_str!("../../scenes/cube.json")),
    ("cylinder", include_str!("../../scenes/cylinder.json")),
    ("disk", include_str!("../../scenes/disk.json")),
    ("lecture", include_str!("../../scenes/lecture.json")),
    ("mesh", include_str!("../../scenes/mesh.json")),
    ("plane", include_str!("../../scenes/plane.json")),
    ("showcase", include_str!("../../scenes/showcase.json")),
    ("sphere", include_str!("../../scenes/sphere.json")),
];

/// One entry of the list.
#[derive(Debug, Clone, Serialize)]
pub struct SceneEntry {
    /// The name to fetch it by.
    pub name: &'static str,
    /// Where to fetch it.
    pub href: String,
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Anti-aliasing samples per axis.
    pub samples: u32,
    /// Objects.
    pub objects: usize,
    /// Lights.
    pub lights: usize,
}

/// The list, worked out once from the embedded documents.
fn entries() -> &'static [SceneEntry] {
    static ENTRIES: OnceLock<Vec<SceneEntry>> = OnceLock::new();
    ENTRIES.get_or_init(|| {
        SCENES
            .iter()
            .filter_map(|(name, text)| {
                // The shipped scenes are valid (a test says so); skip rather than panic.
                let s = scene::parse(text.as_bytes(), &Limits::NONE).ok()?;
                Some(SceneEntry {
                    name,
                    href: format!("/v1/scenes/{name}"),
                    width: s.width,
                    height: s.height,
                    samples: s.samples,
                    objects: s.objects.len(),
                    lights: s.lights.len(),
                })
            })
            .collect()
    })
}

/// The body of `GET /v1/scenes`.
#[derive(Debug, Serialize)]
struct SceneList {
    scenes: &'static [SceneEntry],
}

async fn list() -> Json<SceneList> {
    Json(SceneList { scenes: entries() })
}

/// The embedded document called `name` (`showcase` or `showcase.json`).
pub fn find(name: &str) -> Option<&'static str> {
    let stem = name.strip_suffix(".json").unwrap_or(name);
    SCENES
        .iter()
        .find(|(n, _)| *n == stem)
        .map(|(_, text)| *text)
}

async fn one(Path(name): Path<String>) -> Result<Response, ApiError> {
    let text = find(&name).ok_or_else(|| {
        ApiError::NotFound(format!(
            "there is no example scene `{name}`; GET /v1/scenes lists them"
        ))
    })?;
    let mut res = text.into_response();
    res.headers_mut().insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("application/json"),
    );
    Ok(res)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_scene_file_is_embedded_and_valid() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
        let mut on_disk: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .filter_map(|e| {
                let p = e.ok()?.path();
                (p.extension()? == "json").then(|| p.file_stem()?.to_str().map(String::from))?
            })
            .collect();
        on_disk.sort();
        let embedded: Vec<&str> = SCENES.iter().map(|(n, _)| *n).collect();
        assert_eq!(on_disk, embedded);
        assert_eq!(
            entries().len(),
            SCENES.len(),
            "every embedded scene is valid"
        );
        assert!(find("showcase.json").is_some() && find("showcase").is_some());
        assert!(find("../Cargo.toml").is_none());
    }
}
