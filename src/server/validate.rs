//! `POST /v1/validate`: a scene in, and out either the normalised scene (every default
//! made explicit) with its statistics and the limits it was checked against (200), or
//! every problem with its JSON pointer (422, from [`super::extract::SceneBody`]).
//!
//! ```json
//! { "valid": true,
//!   "scene": { "version": 1, "image": { "width": 5, "height": 5, "samples": 1 }, … },
//!   "statistics": { "width": 5, "height": 5, "pixels": 25, "samples": 1,
//!                   "rays_per_pixel": 1, "primary_rays": 25, "objects": 1,
//!                   "triangles": 0, "lights": 1, "materials": 1, "max_depth": 5 },
//!   "limits": { "max_pixels": 16777216, … } }
//! ```

use axum::Json;
use axum::Router;
use axum::extract::State;
use axum::routing::post;
use serde::Serialize;

use super::AppState;
use super::error::ApiError;
use super::extract::{Accepted, JsonOnly, SceneBody};
use crate::scene::{Scene, SceneDoc};

/// The routes: `POST /v1/validate`.
pub fn router() -> Router<AppState> {
    Router::new().route("/v1/validate", post(validate))
}

/// The answer for a valid scene.
#[derive(Debug, Serialize)]
pub struct Validated {
    /// Always true (an invalid scene is a 422 problem).
    pub valid: bool,
    /// The scene with every default explicit.
    pub scene: SceneDoc,
    /// What tracing it costs.
    pub statistics: Statistics,
    /// The server's limits it was checked against.
    pub limits: LimitsDoc,
}

/// What a scene asks of the renderer.
#[derive(Debug, Serialize)]
pub struct Statistics {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// `width × height`.
    pub pixels: u64,
    /// Anti-aliasing samples per axis.
    pub samples: u32,
    /// Primary rays per pixel: `samples²`.
    pub rays_per_pixel: u64,
    /// Primary rays of the whole frame.
    pub primary_rays: u64,
    /// Objects.
    pub objects: usize,
    /// Mesh triangles over all meshes.
    pub triangles: u64,
    /// Lights.
    pub lights: usize,
    /// Distinct materials.
    pub materials: usize,
    /// Recursion depth of reflection and refraction.
    pub max_depth: u32,
}

/// The server's limits, as configured.
#[derive(Debug, Serialize)]
pub struct LimitsDoc {
    /// Largest `width × height`.
    pub max_pixels: u64,
    /// Largest `image.samples`.
    pub max_samples: u32,
    /// Largest `max_depth`.
    pub max_depth: u32,
    /// Most objects.
    pub max_objects: u64,
    /// Most triangles.
    pub max_triangles: u64,
    /// Largest body in bytes.
    pub max_body_bytes: usize,
}

impl Statistics {
    /// The statistics of `s`.
    pub fn of(s: &Scene) -> Statistics {
        let pixels = s.width as u64 * s.height as u64;
        let rays_per_pixel = s.samples as u64 * s.samples as u64;
        Statistics {
            width: s.width,
            height: s.height,
            pixels,
            samples: s.samples,
            rays_per_pixel,
            primary_rays: pixels * rays_per_pixel,
            objects: s.objects.len(),
            triangles: s.triangles(),
            lights: s.lights.len(),
            materials: s.materials.len(),
            max_depth: s.max_depth,
        }
    }
}

async fn validate(
    State(app): State<AppState>,
    _: Accepted<JsonOnly>,
    body: SceneBody,
) -> Result<Json<Validated>, ApiError> {
    let limits = app.config.limits();
    Ok(Json(Validated {
        valid: true,
        scene: body.scene.normalised(),
        statistics: Statistics::of(&body.scene),
        limits: LimitsDoc {
            max_pixels: limits.max_pixels,
            max_samples: limits.max_samples,
            max_depth: limits.max_depth,
            max_objects: limits.max_objects,
            max_triangles: limits.max_triangles,
            max_body_bytes: app.config.max_body_bytes,
        },
    }))
}
