//! The answer of an explanation: the types [`explain`](super::explain) fills in, serialised
//! to JSON as `raytile trace --format json` and `/v1/trace` give them. Field order is the
//! wire order.

use glam::DVec3;
use serde::Serialize;

use super::Candidates;
use crate::geometry::Ray;
use crate::scene::Material;

/// A ray in the lecture's homogeneous form: `origin` with w = 1, `direction` with w = 0.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Ray4 {
    /// `[x, y, z, 1]`.
    pub origin: [f64; 4],
    /// `[Δx, Δy, Δz, 0]` (not normalised).
    pub direction: [f64; 4],
}

impl From<&Ray> for Ray4 {
    fn from(r: &Ray) -> Ray4 {
        Ray4 {
            origin: point4(r.origin),
            direction: vector4(r.dir),
        }
    }
}

pub(super) fn point4(p: DVec3) -> [f64; 4] {
    [p.x, p.y, p.z, 1.0]
}

pub(super) fn vector4(d: DVec3) -> [f64; 4] {
    [d.x, d.y, d.z, 0.0]
}

/// One pixel's explanation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Explanation {
    /// Column.
    pub u: u32,
    /// Row.
    pub v: u32,
    /// The image and its sampling.
    pub image: ImageInfo,
    /// The primary ray through the pixel's centre.
    pub primary: PrimaryRay,
    /// Which objects each ray was tested against: `"all"` or `"bvh"`.
    pub candidates: Candidates,
    /// The ray tree, from the primary ray.
    pub tree: RayNode,
    /// The tree's rays and shadow rays as lines on the image, for drawing them over it.
    pub screen: Vec<super::screen::ScreenRay>,
    /// The pixel's colour as rendered.
    pub colour: FinalColour,
    /// Whether anything was left out of the tree (`truncation` says what and where).
    pub truncated: bool,
    /// The bounds the answer keeps, and what each left out.
    pub truncation: Truncation,
    /// Remarks a reader needs (anti-aliasing, truncation).
    pub notes: Vec<String>,
}

/// The image the pixel belongs to.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ImageInfo {
    /// Width `w`.
    pub width: u32,
    /// Height `h`.
    pub height: u32,
    /// `s`: `s × s` rays per pixel.
    pub samples: u32,
    /// Output gamma, if any.
    pub gamma: Option<f64>,
    /// Focal length `f`.
    pub focal_length: f64,
    /// Deepest recursion.
    pub max_depth: u32,
    /// Number of objects.
    pub objects: usize,
    /// Number of lights.
    pub lights: usize,
}

/// The primary ray in both spaces.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PrimaryRay {
    /// Image point `(u + ½, v + ½)` the ray passes through.
    pub image_point: [f64; 2],
    /// `[0,0,0,1] + λ[−1 + x·2/w, −h/w + y·2/w, f, 0]` in camera space.
    pub camera: Ray4,
    /// camera → world, rows.
    pub world_from_camera: [[f64; 4]; 4],
    /// The same ray in world space (`λ` unchanged).
    pub world: Ray4,
    /// The terms of the camera-space direction, as the lecture works it out.
    pub direction_terms: DirectionTerms,
}

/// The terms of `d = [−1 + x·2/w, −h/w + y·2/w, f, 0]`, each computed as the camera
/// computes it, so that `−1 + x_term` and `−aspect + y_term` are `d`'s components.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct DirectionTerms {
    /// `x · 2 / w`.
    pub x_term: f64,
    /// `h / w`.
    pub aspect: f64,
    /// `y · 2 / w`.
    pub y_term: f64,
}

impl DirectionTerms {
    /// The terms for the image point `(x, y)` of a `w × h` image.
    pub fn new(x: f64, y: f64, width: u32, height: u32) -> DirectionTerms {
        let (w, h) = (f64::from(width), f64::from(height));
        DirectionTerms {
            x_term: x * 2.0 / w,
            aspect: h / w,
            y_term: y * 2.0 / w,
        }
    }
}

/// How a ray of the tree came about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// The pixel's ray.
    Primary,
    /// The mirror ray of a surface with `mirror`.
    Reflected,
    /// The refracted ray of a surface with `transmission`.
    Refracted,
    /// A refracted ray turned back by total internal reflection (along the mirror ray).
    TotalInternalReflection,
}

/// One ray of the tree: what it was tested against, what it hit, how that was shaded.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RayNode {
    /// How it came about.
    pub role: Role,
    /// Recursion depth (primary 0).
    pub depth: u32,
    /// The ray in world space.
    pub ray: Ray4,
    /// Hits count for `λ` above this.
    pub lambda_min: f64,
    /// Objects tested by the chosen candidate rule, listed or not.
    pub tested: usize,
    /// Number of objects in the scene.
    pub objects: usize,
    /// The tests listed, in scene order: at most `max_tests` and the chosen hit's.
    pub tests: Vec<ObjectTest>,
    /// Objects tested but not listed (past `max_tests`, or the answer's size budget spent).
    pub tests_unlisted: usize,
    /// The first hit, if any.
    pub hit: Option<HitInfo>,
    /// The shading of the hit (absent for a miss).
    pub shading: Option<Shading>,
    /// The linear colour this ray returns.
    pub colour: [f64; 3],
    /// Set when the ray was not broken down (the explanation's ray budget or its size
    /// budget was spent); its colour is still the tracer's.
    pub truncated: bool,
}

/// One object's intersection test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ObjectTest {
    /// Index in the scene's `objects`.
    pub object: u32,
    /// Its name.
    pub name: Option<String>,
    /// `"sphere"`, `"cube"`, …
    pub shape: &'static str,
    /// `T⁻¹` (world → object), rows.
    pub inverse_transform: [[f64; 4]; 4],
    /// The ray carried into object space by `T⁻¹`.
    pub object_ray: Ray4,
    /// Quadratics solved (sphere; cylinder and cone sides).
    pub quadratics: Vec<Quadratic>,
    /// Planar faces tested (cube faces, caps, plane, disk).
    pub faces: Vec<FaceCheck>,
    /// Triangle tests listed: at most `max_triangles` misses and `max_triangles` other
    /// hits, and the hit that counts.
    pub triangles: Vec<TriangleCheck>,
    /// Triangle tests made but not listed.
    pub triangles_unlisted: usize,
    /// For a cone side parallel to a generator line: the quadratic degenerates to a line.
    pub linear_side: bool,
    /// This object's first hit in range, if any.
    pub lambda: Option<f64>,
    /// Which part of the object that hit is on.
    pub part: Option<String>,
    /// Whether this is the ray's chosen (first) hit.
    pub chosen: bool,
}

/// A quadratic `a λ² + b λ + c = 0` and its roots.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Quadratic {
    /// `"sphere"` or `"side"`.
    pub surface: &'static str,
    /// `a`.
    pub a: f64,
    /// `b`.
    pub b: f64,
    /// `c`.
    pub c: f64,
    /// `b² − 4ac`.
    pub discriminant: f64,
    /// The real roots, smaller first, with their verdicts.
    pub roots: Vec<Root>,
}

/// A root and whether it counts.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Root {
    /// `λ`.
    pub lambda: f64,
    /// The object-space point there.
    pub point: [f64; 4],
    /// Whether it is the object's hit.
    pub counts: bool,
    /// Why (not).
    pub why: &'static str,
}

/// A planar face test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FaceCheck {
    /// `"+x"`, `"top"`, `"plane"`, …
    pub face: &'static str,
    /// `λ` where the ray meets the face's plane, absent when parallel.
    pub lambda: Option<f64>,
    /// The object-space point there; the two in-face coordinates decide `within`.
    pub point: Option<[f64; 4]>,
    /// Whether the point lies within the face.
    pub within: bool,
    /// Whether it is the object's hit.
    pub counts: bool,
    /// Why (not).
    pub why: &'static str,
}

/// A Möller–Trumbore triangle test.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TriangleCheck {
    /// Index in the mesh's `indices`.
    pub triangle: u32,
    /// Barycentric `u`, `v`, absent when the ray is parallel to the triangle.
    pub barycentric: Option<[f64; 2]>,
    /// `λ`, absent when parallel.
    pub lambda: Option<f64>,
    /// Whether the triangle is hit in range.
    pub hit: bool,
    /// Whether it is the object's hit.
    pub counts: bool,
    /// Why (not).
    pub why: &'static str,
}

/// The chosen hit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HitInfo {
    /// Object index.
    pub object: u32,
    /// Its name.
    pub name: Option<String>,
    /// Its shape.
    pub shape: &'static str,
    /// The ray parameter.
    pub lambda: f64,
    /// The part: a cube face, `"side"`, `"top"`, a triangle, …
    pub part: String,
    /// The cube face, for cubes (as hit data reports it).
    pub face: Option<&'static str>,
    /// Object-space point `[x, y, z, 1]`.
    pub object_point: [f64; 4],
    /// World point `[x, y, z, 1]`.
    pub point: [f64; 4],
    /// Reported unit world normal `[x, y, z, 0]` (outward for closed shapes).
    pub normal: [f64; 4],
    /// Whether the ray arrives on the outside of the reported normal.
    pub front: bool,
}

/// The Phong terms and the secondary rays of a hit.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Shading {
    /// The material (defaults applied).
    pub material: MaterialInfo,
    /// `n`: the unit normal turned to face the ray.
    pub n: [f64; 3],
    /// `v`: unit vector back to the ray's origin.
    pub v: [f64; 3],
    /// Secondary rays start this far off the surface, along `n`.
    pub offset: f64,
    /// `ambient ⊙ m.ambient`.
    pub ambient: [f64; 3],
    /// One entry per light, in scene order: at most
    /// [`MAX_LIGHTS_LISTED`](super::MAX_LIGHTS_LISTED), while the size budget lasts.
    pub lights: Vec<LightInfo>,
    /// Lights not listed; they are shaded all the same, and their terms are in `colour`.
    pub lights_unlisted: usize,
    /// The reflection, when the material has `mirror` and the depth allows it.
    pub reflection: Option<Box<Secondary>>,
    /// The refraction, when the material has `transmission` and the depth allows it.
    pub refraction: Option<Box<Secondary>>,
    /// Why there are no secondary rays, when there are none.
    pub no_secondary: Option<String>,
}

/// A material with every default applied.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MaterialInfo {
    /// Ambient reflectance.
    pub ambient: [f64; 3],
    /// Diffuse reflectance.
    pub diffuse: [f64; 3],
    /// Specular reflectance.
    pub specular: [f64; 3],
    /// Phong exponent.
    pub shininess: f64,
    /// Mirror reflectance.
    pub mirror: [f64; 3],
    /// Transmittance.
    pub transmission: [f64; 3],
    /// Index of refraction.
    pub ior: f64,
}

impl From<&Material> for MaterialInfo {
    fn from(m: &Material) -> Self {
        MaterialInfo {
            ambient: m.ambient.to_array(),
            diffuse: m.diffuse.to_array(),
            specular: m.specular.to_array(),
            shininess: m.shininess,
            mirror: m.mirror.to_array(),
            transmission: m.transmission.to_array(),
            ior: m.ior,
        }
    }
}

/// One light at a hit: its shadow ray and its Phong terms.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LightInfo {
    /// Index in the scene's `lights`.
    pub light: usize,
    /// `"point"`, `"directional"` or `"spot"`.
    pub kind: &'static str,
    /// Its colour.
    pub colour: [f64; 3],
    /// The shadow ray (toward a point light it reaches the light at `λ = 1`).
    pub shadow_ray: Ray4,
    /// Hits block it for `λ` in `(lambda_min, lambda_max)`.
    pub lambda_min: f64,
    /// Upper bound (`null` for infinity: a directional light).
    pub lambda_max: Option<f64>,
    /// The point lies outside a spot light's cone (nothing else computed).
    pub outside_cone: bool,
    /// Whether the shadow ray is blocked.
    pub blocked: bool,
    /// What blocks it first.
    pub blocker: Option<Blocker>,
    /// Unit vector to the light.
    pub l: [f64; 3],
    /// `n · l`.
    pub n_dot_l: f64,
    /// `r · v`.
    pub r_dot_v: f64,
    /// `L.colour ⊙ m.diffuse · max(0, n·l)`.
    pub diffuse: [f64; 3],
    /// `L.colour ⊙ m.specular · max(0, r·v)^shininess`.
    pub specular: [f64; 3],
}

/// The object a shadow ray hits first.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Blocker {
    /// Object index.
    pub object: u32,
    /// Its name.
    pub name: Option<String>,
    /// Where along the shadow ray.
    pub lambda: f64,
}

/// A reflected or refracted child ray and what it adds.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Secondary {
    /// `m.mirror` or `m.transmission`.
    pub coefficient: [f64; 3],
    /// The child ray.
    pub ray: RayNode,
    /// `coefficient ⊙ ray.colour`.
    pub contribution: [f64; 3],
}

/// The pixel's colour as the PNG has it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FinalColour {
    /// The colour of the pixel-centre ray (the tree's root).
    pub centre_linear: [f64; 3],
    /// With `s > 1`: each sample's image point and linear colour, in the order averaged.
    pub samples: Vec<Sample>,
    /// The pixel's linear colour: the mean of its samples.
    pub linear: [f64; 3],
    /// Gamma, if the scene asks for it.
    pub gamma: Option<f64>,
    /// `linear^(1/gamma)` (or `linear`), before clamping.
    pub encoded: [f64; 3],
    /// `round(255 · clamp(encoded, 0, 1))`: the PNG's pixel.
    pub rgb8: [u8; 3],
    /// `#rrggbb`.
    pub hex: String,
}

/// One anti-aliasing sample.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sample {
    /// Image point `(x, y)`.
    pub image_point: [f64; 2],
    /// Its linear colour.
    pub linear: [f64; 3],
}

/// The bounds an explanation keeps, whatever the scene and options, and what each left
/// out.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Truncation {
    /// Most rays broken down.
    pub max_rays: usize,
    /// Most object tests listed per ray (the chosen hit's is listed besides).
    pub max_tests: usize,
    /// Most triangle misses, and other hits, listed per mesh and ray.
    pub max_triangles: usize,
    /// Most lights listed per hit.
    pub max_lights: usize,
    /// The size budget of the tree: bytes of the JSON answer
    /// ([`MAX_ANSWER_BYTES`](super::MAX_ANSWER_BYTES)).
    pub max_bytes: usize,
    /// Bytes of it spent (about: each ray's own fields are estimated).
    pub bytes: usize,
    /// Rays in the tree that are not broken down (`truncated`).
    pub rays_not_broken_down: usize,
    /// Object tests left out, over all rays.
    pub tests_unlisted: usize,
    /// Triangle tests left out, over all object tests.
    pub triangles_unlisted: usize,
    /// Lights left out, over all hits.
    pub lights_unlisted: usize,
    /// Where the size budget ran out, if it did.
    pub budget_spent_at: Option<SpentAt>,
}

/// The ray at which the size budget ran out: every ray traced after it is not broken down.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SpentAt {
    /// Its number, as the text numbers rays: from 1, in the order they are traced.
    pub ray: usize,
    /// Its JSON pointer in the answer, e.g. `/tree/shading/reflection/ray`.
    pub pointer: String,
}
