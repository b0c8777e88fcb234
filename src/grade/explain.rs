//! Explaining one pixel (`raytile trace`, `/v1/trace`): its complete ray tree with every
//! intermediate value of the lecture's computation, as JSON ([`Explanation`]) and as text
//! laid out like the lecture's worked example ([`to_text`]).
//!
//! Nothing here repeats the mathematics: each value is what the tracer itself computes,
//! captured through [`Probe`] (the shape tests report their quadratics, faces and
//! triangles) or returned by the shading functions the renderer calls (`light_term`,
//! `bounce`, `facing_normal`). The colour of every ray is summed in the order
//! [`Shader::trace`] sums it, and the final colour is [`Renderer::pixel_colour`] quantised
//! by [`quantise`], so the 8-bit colour shown is the rendered PNG's pixel exactly.
//!
//! For `scenes/lecture.json`, pixel (2, 2):
//!
//! ```text
//! Primary ray (world space):  p(λ) = [0, 0, 0, 1] + λ [0, 0, 1, 0]
//! object 0 "ball" (sphere)
//!   T⁻¹ = [1, 0, 0, -1; 0, 1, 0, 0; 0, 0, 1, -2; 0, 0, 0, 1]
//!   ray in object space: [-1, 0, -2, 1] + λ [0, 0, 1, 0]
//!   a = 1, b = -4, c = 4, discriminant 0: λ = 2 counts
//! ```

use std::fmt::Write as _;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::geometry::hit::{FaceTest, Probe, QuadraticTest, TriangleTest};
use crate::geometry::{Ray, Shape, World, ray::PRIMARY_LAMBDA_MIN};
use crate::render::shade::{
    SECONDARY_LAMBDA_MIN, Shader, bounce, facing_normal, light_term, surface_offset,
};
use crate::render::{RayCount, Renderer, quantise};
use crate::scene::{Light, Material};

/// Scenes with at most this many objects are explained against every object by default;
/// larger ones against the BVH's candidates only.
pub const AUTO_ALL_MAX_OBJECTS: usize = 64;

/// Which objects each ray of the explanation is tested against.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Candidates {
    /// `all` for scenes of at most [`AUTO_ALL_MAX_OBJECTS`] objects, else `bvh`.
    #[default]
    Auto,
    /// Every object, in scene order: what the lecture does by hand.
    All,
    /// Only the objects whose bounding box the ray enters (and unbounded planes).
    Bvh,
}

/// What to include in an explanation.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ExplainOptions {
    /// Which objects are listed for each ray.
    pub candidates: Candidates,
    /// At most this many triangle tests are listed per mesh and ray (hits always are).
    pub max_triangles: usize,
    /// At most this many rays (primary, reflected, refracted) are expanded; deeper ones
    /// still contribute their exact colour but are not broken down.
    pub max_rays: usize,
}

impl Default for ExplainOptions {
    fn default() -> Self {
        ExplainOptions {
            candidates: Candidates::Auto,
            max_triangles: 16,
            max_rays: 64,
        }
    }
}

/// Why a pixel cannot be explained.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ExplainError {
    /// The pixel lies outside the image.
    #[error("pixel ({u}, {v}) is outside the {width} × {height} image")]
    OutsideImage {
        /// Column asked for.
        u: u32,
        /// Row asked for.
        v: u32,
        /// Image width.
        width: u32,
        /// Image height.
        height: u32,
    },
}

/// Checks that `(u, v)` is a pixel of the renderer's image (callers that take the pixel
/// from a user check this before [`explain`], which would otherwise extrapolate).
pub fn check_pixel(r: &Renderer, u: u32, v: u32) -> Result<(), ExplainError> {
    if u < r.scene.width && v < r.scene.height {
        Ok(())
    } else {
        Err(ExplainError::OutsideImage {
            u,
            v,
            width: r.scene.width,
            height: r.scene.height,
        })
    }
}

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

fn point4(p: DVec3) -> [f64; 4] {
    [p.x, p.y, p.z, 1.0]
}

fn vector4(d: DVec3) -> [f64; 4] {
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
    /// The pixel's colour as rendered.
    pub colour: FinalColour,
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

impl Role {
    fn label(self) -> &'static str {
        match self {
            Role::Primary => "primary",
            Role::Reflected => "reflected",
            Role::Refracted => "refracted",
            Role::TotalInternalReflection => "refracted (total internal reflection)",
        }
    }
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
    /// Objects tested (by the chosen candidate rule) and the scene's total.
    pub tested: usize,
    /// Number of objects in the scene.
    pub objects: usize,
    /// One entry per object tested, in scene order.
    pub tests: Vec<ObjectTest>,
    /// The first hit, if any.
    pub hit: Option<HitInfo>,
    /// The shading of the hit (absent for a miss).
    pub shading: Option<Shading>,
    /// The linear colour this ray returns.
    pub colour: [f64; 3],
    /// Set when the ray was not broken down (the explanation's ray budget was spent);
    /// its colour is still the tracer's.
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
    /// Triangle tests listed (at most `max_triangles` misses, every hit).
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
    /// One entry per light.
    pub lights: Vec<LightInfo>,
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

/// Records what a shape test reports.
#[derive(Default)]
struct Recorder {
    object_ray: Option<Ray>,
    quadratics: Vec<QuadraticTest>,
    faces: Vec<FaceTest>,
    triangles: Vec<TriangleTest>,
}

impl Probe for Recorder {
    fn object(&mut self, _index: u32, object_ray: &Ray) {
        self.object_ray = Some(*object_ray);
    }
    fn quadratic(&mut self, q: &QuadraticTest) {
        self.quadratics.push(*q);
    }
    fn face(&mut self, f: &FaceTest) {
        self.faces.push(*f);
    }
    fn triangle(&mut self, t: &TriangleTest) {
        self.triangles.push(*t);
    }
    fn active(&self) -> bool {
        true
    }
}

/// The name of a part of a shape, as the shape files number them.
pub fn part_label(shape: &Shape, part: u32) -> String {
    shape.part_label(part).into_owned()
}

struct Explainer<'a> {
    r: &'a Renderer,
    opts: &'a ExplainOptions,
    mode: Candidates,
    rays_left: usize,
    truncated: bool,
}

/// Explains pixel `(u, v)` (see the module documentation). A pixel outside the image is
/// extrapolated along the same formula; [`check_pixel`] refuses it first.
pub fn explain(r: &Renderer, u: u32, v: u32, opts: &ExplainOptions) -> Explanation {
    let scene = &r.scene;
    let mode = match opts.candidates {
        Candidates::Auto if scene.objects.len() <= AUTO_ALL_MAX_OBJECTS => Candidates::All,
        Candidates::Auto => Candidates::Bvh,
        c => c,
    };
    let (x, y) = (u as f64 + 0.5, v as f64 + 0.5);
    let camera_ray = r.camera.camera_ray(x, y);
    let world_ray = r.camera.pixel_centre(u, v);
    let mut ex = Explainer {
        r,
        opts,
        mode,
        rays_left: opts.max_rays.max(1),
        truncated: false,
    };
    let tree = ex.node(&world_ray, Role::Primary, 0, PRIMARY_LAMBDA_MIN);

    let mut notes = Vec::new();
    let s = scene.samples;
    let mut samples = Vec::new();
    if s > 1 {
        notes.push(format!(
            "The image takes {s} × {s} samples per pixel: the ray tree is the pixel-centre \
             ray's (as hit data uses); the final colour is the mean of the {} samples, as rendered.",
            s * s
        ));
        // The same points, in the same order, as `Renderer::pixel_colour` averages them.
        let shader = Shader {
            scene,
            world: &r.world,
        };
        let sf = s as f64;
        for j in 0..s {
            for i in 0..s {
                let px = u as f64 + (i as f64 + 0.5) / sf;
                let py = v as f64 + (j as f64 + 0.5) / sf;
                let c = shader.trace(
                    &r.camera.through(px, py),
                    0,
                    PRIMARY_LAMBDA_MIN,
                    &mut RayCount(0),
                );
                samples.push(Sample {
                    image_point: [px, py],
                    linear: c.to_array(),
                });
            }
        }
    }
    if ex.truncated {
        notes.push(format!(
            "Only the first {} rays are broken down; the colours of the others are the \
             tracer's, exactly.",
            opts.max_rays.max(1)
        ));
    }
    if mode == Candidates::Bvh {
        notes.push(
            "Each ray lists only the BVH's candidates: objects whose bounding box it enters, \
             and unbounded planes."
                .into(),
        );
    }

    let linear = r.pixel_colour(u, v, &mut RayCount(0));
    let encoded = match scene.gamma {
        Some(g) => DVec3::new(
            linear.x.powf(1.0 / g),
            linear.y.powf(1.0 / g),
            linear.z.powf(1.0 / g),
        ),
        None => linear,
    };
    let rgb8 = quantise(linear, scene.gamma);
    Explanation {
        u,
        v,
        image: ImageInfo {
            width: scene.width,
            height: scene.height,
            samples: s,
            gamma: scene.gamma,
            focal_length: scene.camera.focal_length,
            max_depth: scene.max_depth,
            objects: scene.objects.len(),
            lights: scene.lights.len(),
        },
        primary: PrimaryRay {
            image_point: [x, y],
            camera: (&camera_ray).into(),
            world_from_camera: scene.camera.world_from_camera.forward_rows(),
            world: (&world_ray).into(),
        },
        candidates: mode,
        colour: FinalColour {
            centre_linear: tree.colour,
            samples,
            linear: linear.to_array(),
            gamma: scene.gamma,
            encoded: encoded.to_array(),
            rgb8,
            hex: format!("#{:02x}{:02x}{:02x}", rgb8[0], rgb8[1], rgb8[2]),
        },
        tree,
        notes,
    }
}

impl Explainer<'_> {
    /// One ray: mirrors [`Shader::trace`] step for step, recording as it goes.
    fn node(&mut self, ray: &Ray, role: Role, depth: u32, t_min: f64) -> RayNode {
        let r = self.r;
        let scene = &r.scene;
        let world = &r.world;
        if self.rays_left == 0 {
            self.truncated = true;
            let shader = Shader { scene, world };
            let c = shader.trace(ray, depth, t_min, &mut RayCount(0));
            return RayNode {
                role,
                depth,
                ray: ray.into(),
                lambda_min: t_min,
                tested: 0,
                objects: world.len(),
                tests: Vec::new(),
                hit: None,
                shading: None,
                colour: c.to_array(),
                truncated: true,
            };
        }
        self.rays_left -= 1;

        let closest = world.closest(ray, t_min, f64::INFINITY);
        let tests = self.object_tests(ray, t_min, closest.map(|h| h.object));
        let tested = tests.len();
        let Some(hit) = closest else {
            return RayNode {
                role,
                depth,
                ray: ray.into(),
                lambda_min: t_min,
                tested,
                objects: world.len(),
                tests,
                hit: None,
                shading: None,
                colour: scene.background.to_array(),
                truncated: false,
            };
        };
        let s = world.surface(ray, &hit);
        let object = &scene.objects[hit.object as usize];
        let m = &scene.materials[object.material as usize];
        let n = facing_normal(&s, ray.dir);

        let mut c = scene.ambient * m.ambient;
        let ambient = c;
        let mut lights = Vec::with_capacity(scene.lights.len());
        for (k, light) in scene.lights.iter().enumerate() {
            let t = light_term(world, light, &s, n, ray.dir, m);
            c += t.diffuse + t.specular;
            // `occluded` only says whether; the first blocker is found here, for the reader.
            let blocker = if t.blocked {
                world
                    .closest(&t.shadow_ray, SECONDARY_LAMBDA_MIN, t.shadow_t_max)
                    .map(|b| Blocker {
                        object: b.object,
                        name: scene.object_name(b.object).map(str::to_owned),
                        lambda: b.lambda,
                    })
            } else {
                None
            };
            let (kind, colour) = match *light {
                Light::Point { colour, .. } => ("point", colour),
                Light::Directional { colour, .. } => ("directional", colour),
                Light::Spot { colour, .. } => ("spot", colour),
            };
            lights.push(LightInfo {
                light: k,
                kind,
                colour: colour.to_array(),
                shadow_ray: (&t.shadow_ray).into(),
                lambda_min: SECONDARY_LAMBDA_MIN,
                lambda_max: t.shadow_t_max.is_finite().then_some(t.shadow_t_max),
                outside_cone: t.outside_cone,
                blocked: t.blocked,
                blocker,
                l: t.l.to_array(),
                n_dot_l: t.n_dot_l,
                r_dot_v: t.r_dot_v,
                diffuse: t.diffuse.to_array(),
                specular: t.specular.to_array(),
            });
        }

        let mut reflection = None;
        let mut refraction = None;
        let has_secondary = m.mirror != DVec3::ZERO || m.transmission != DVec3::ZERO;
        let no_secondary = if !has_secondary {
            Some("the material has neither mirror nor transmission".to_owned())
        } else if depth >= scene.max_depth {
            Some(format!(
                "depth {depth} reached max_depth {}: no further rays",
                scene.max_depth
            ))
        } else {
            let b = bounce(&s, n, ray.dir, m.ior);
            if m.mirror != DVec3::ZERO {
                let child = self.node(
                    &b.reflected,
                    Role::Reflected,
                    depth + 1,
                    SECONDARY_LAMBDA_MIN,
                );
                let add = m.mirror * DVec3::from_array(child.colour);
                c += add;
                reflection = Some(Box::new(Secondary {
                    coefficient: m.mirror.to_array(),
                    ray: child,
                    contribution: add.to_array(),
                }));
            }
            if m.transmission != DVec3::ZERO {
                let role = if b.total_internal_reflection {
                    Role::TotalInternalReflection
                } else {
                    Role::Refracted
                };
                let child = self.node(&b.refracted, role, depth + 1, SECONDARY_LAMBDA_MIN);
                let add = m.transmission * DVec3::from_array(child.colour);
                c += add;
                refraction = Some(Box::new(Secondary {
                    coefficient: m.transmission.to_array(),
                    ray: child,
                    contribution: add.to_array(),
                }));
            }
            None
        };

        let shape = &object.shape;
        RayNode {
            role,
            depth,
            ray: ray.into(),
            lambda_min: t_min,
            tested,
            objects: world.len(),
            tests,
            hit: Some(HitInfo {
                object: hit.object,
                name: object.name.clone(),
                shape: shape.name(),
                lambda: s.lambda,
                part: part_label(shape, hit.part),
                face: s.face.map(|f| f.label()),
                object_point: point4(s.object_point),
                point: point4(s.point),
                normal: vector4(s.normal),
                front: s.front,
            }),
            shading: Some(Shading {
                material: m.into(),
                n: n.to_array(),
                v: (-ray.dir.normalize()).to_array(),
                offset: surface_offset(s.point),
                ambient: ambient.to_array(),
                lights,
                reflection,
                refraction,
                no_secondary,
            }),
            colour: c.to_array(),
            truncated: false,
        }
    }

    /// The tests of every candidate object, each searched over `(t_min, ∞)` on its own.
    fn object_tests(&self, ray: &Ray, t_min: f64, chosen: Option<u32>) -> Vec<ObjectTest> {
        let world: &World = &self.r.world;
        let list: Vec<u32> = match self.mode {
            Candidates::Bvh => world.candidates(ray, t_min, f64::INFINITY),
            _ => (0..world.len() as u32).collect(),
        };
        list.into_iter()
            .map(|i| self.object_test(i, ray, t_min, chosen == Some(i)))
            .collect()
    }

    fn object_test(&self, i: u32, ray: &Ray, t_min: f64, chosen: bool) -> ObjectTest {
        let world = &self.r.world;
        let object = &self.r.scene.objects[i as usize];
        let shape = &object.shape;
        let mut rec = Recorder::default();
        let result = world.intersect_object(i, ray, t_min, f64::INFINITY, &mut rec);
        let object_ray = rec
            .object_ray
            .unwrap_or_else(|| ray.transformed(&world.transform(i).inverse));
        let hit_part = result.map(|(_, p)| part_label(shape, p));
        let side_hit = result.filter(|&(_, p)| p == 0).map(|(t, _)| t);
        let bounded_height = shape.bounded_quadric();

        let quadratics = rec
            .quadratics
            .iter()
            .map(|q| Quadratic {
                surface: q.surface,
                a: q.a,
                b: q.b,
                c: q.c,
                discriminant: q.discriminant,
                roots: q
                    .roots
                    .iter()
                    .flatten()
                    .map(|&t| {
                        let p = object_ray.at(t);
                        let counts = side_hit == Some(t);
                        let why = if counts {
                            "the object's first hit"
                        } else if t <= t_min {
                            "behind the ray's start (λ ≤ λmin)"
                        } else if bounded_height && !(-1.0..=1.0).contains(&p.y) {
                            "outside −1 ≤ y ≤ 1"
                        } else {
                            "farther than the object's first hit"
                        };
                        Root {
                            lambda: t,
                            point: point4(p),
                            counts,
                            why,
                        }
                    })
                    .collect(),
            })
            .collect();

        let faces = rec
            .faces
            .iter()
            .map(|f| {
                let counts = match (result, &hit_part) {
                    (Some((t, _)), Some(label)) => {
                        f.within && f.lambda == Some(t) && f.face == label
                    }
                    _ => false,
                };
                let why = match f.lambda {
                    None => "parallel to the face (|Δ| < 1e-12): skipped",
                    Some(_) if counts => "the object's first hit",
                    Some(_) if !f.within => "outside the face",
                    Some(t) if t <= t_min => "behind the ray's start (λ ≤ λmin)",
                    Some(_) => "farther than the object's first hit",
                };
                FaceCheck {
                    face: f.face,
                    lambda: f.lambda,
                    point: f.point.map(point4),
                    within: f.within,
                    counts,
                    why,
                }
            })
            .collect();

        let mut triangles = Vec::new();
        let mut unlisted = 0;
        let mut misses_listed = 0;
        for t in &rec.triangles {
            let counts = t.hit && result.is_some_and(|(_, p)| p == t.triangle);
            if !t.hit && misses_listed >= self.opts.max_triangles {
                unlisted += 1;
                continue;
            }
            if !t.hit {
                misses_listed += 1;
            }
            let why = match t.uvt {
                None => "parallel to the triangle's plane",
                Some(_) if counts => "the object's first hit",
                Some([a, b, _]) if a < 0.0 || b < 0.0 || a + b > 1.0 => {
                    "outside the triangle (u, v ≥ 0 and u + v ≤ 1 fail)"
                }
                Some([_, _, l]) if l <= t_min => "behind the ray's start (λ ≤ λmin)",
                Some(_) => "farther than the object's first hit",
            };
            triangles.push(TriangleCheck {
                triangle: t.triangle,
                barycentric: t.uvt.map(|[a, b, _]| [a, b]),
                lambda: t.uvt.map(|[_, _, l]| l),
                hit: t.hit,
                counts,
                why,
            });
        }

        ObjectTest {
            object: i,
            name: object.name.clone(),
            shape: shape.name(),
            inverse_transform: world.transform(i).inverse_rows(),
            object_ray: (&object_ray).into(),
            quadratics,
            faces,
            triangles,
            triangles_unlisted: unlisted,
            linear_side: shape.linear_side() && rec.quadratics.is_empty(),
            lambda: result.map(|(t, _)| t),
            part: hit_part,
            chosen,
        }
    }
}

// ---------------------------------------------------------------------------------------
// The text form.

/// A number as the lecture writes it: integers without a decimal point, others in
/// their shortest round-trip form (so the digits are exactly the computed ones).
fn num(x: f64) -> String {
    if x == 0.0 {
        // −0 and 0 are the same number; the lecture writes 0.
        "0".into()
    } else if x.is_infinite() {
        if x > 0.0 {
            "∞".into()
        } else {
            "−∞".into()
        }
    } else if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{x:.0}")
    } else {
        format!("{x:?}")
    }
}

fn vec_text(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|&x| num(x)).collect();
    format!("[{}]", parts.join(", "))
}

fn ray_text(r: &Ray4) -> String {
    format!("{} + λ {}", vec_text(&r.origin), vec_text(&r.direction))
}

fn matrix_text(m: &[[f64; 4]; 4], indent: &str, label: &str) -> String {
    let cells: Vec<Vec<String>> = m
        .iter()
        .map(|row| row.iter().map(|&x| num(x)).collect())
        .collect();
    // Each column as wide as its widest entry, as a matrix is written by hand.
    let widths: Vec<usize> = (0..4)
        .map(|j| {
            cells
                .iter()
                .map(|r| r[j].chars().count())
                .max()
                .unwrap_or(1)
        })
        .collect();
    let mut out = String::new();
    let pad = " ".repeat(label.chars().count());
    for (k, row) in cells.iter().enumerate() {
        let body: Vec<String> = row
            .iter()
            .zip(&widths)
            .map(|(s, &w)| format!("{s:>w$}"))
            .collect();
        let lead = if k == 0 { label } else { &pad };
        let _ = writeln!(out, "{indent}{lead}[ {} ]", body.join("  "));
    }
    out
}

fn name_text(object: u32, name: &Option<String>) -> String {
    match name {
        Some(n) => format!("object {object} \"{n}\""),
        None => format!("object {object}"),
    }
}

/// The explanation as text, laid out like the lecture's worked example.
pub fn to_text(e: &Explanation) -> String {
    let mut o = String::new();
    let i = &e.image;
    let _ = writeln!(
        o,
        "Pixel ({}, {}) of a {} × {} image (focal length f = {}, {} × {} samples per pixel, max_depth {})",
        e.u,
        e.v,
        i.width,
        i.height,
        num(i.focal_length),
        i.samples,
        i.samples,
        i.max_depth
    );
    let p = &e.primary;
    let _ = writeln!(
        o,
        "\nPrimary ray through the image point ({}, {}):\n  d = [-1 + x·2/w, -h/w + y·2/w, f, 0]",
        num(p.image_point[0]),
        num(p.image_point[1])
    );
    let _ = writeln!(o, "  camera space: p(λ) = {}", ray_text(&p.camera));
    if p.camera == p.world {
        let _ = writeln!(
            o,
            "  world space:  p(λ) = {} (the camera is at the origin)",
            ray_text(&p.world)
        );
    } else {
        o.push_str(&matrix_text(
            &p.world_from_camera,
            "  ",
            "camera → world = ",
        ));
        let _ = writeln!(o, "  world space:  p(λ) = {}", ray_text(&p.world));
    }
    node_text(&mut o, &e.tree, "", "Ray 1", &mut 1);

    let c = &e.colour;
    let _ = writeln!(o, "\nFinal colour");
    if !c.samples.is_empty() {
        let _ = writeln!(o, "  centre ray:   {}", vec_text(&c.centre_linear));
        for s in &c.samples {
            let _ = writeln!(
                o,
                "  sample at ({}, {}): {}",
                num(s.image_point[0]),
                num(s.image_point[1]),
                vec_text(&s.linear)
            );
        }
        let _ = writeln!(o, "  mean (linear): {}", vec_text(&c.linear));
    } else {
        let _ = writeln!(o, "  linear:       {}", vec_text(&c.linear));
    }
    if let Some(g) = c.gamma {
        let _ = writeln!(o, "  c^(1/{}):     {}", num(g), vec_text(&c.encoded));
    }
    let _ = writeln!(
        o,
        "  8-bit:        round(255 · clamp(c, 0, 1)) = [{}, {}, {}]  {}",
        c.rgb8[0], c.rgb8[1], c.rgb8[2], c.hex
    );
    if !e.notes.is_empty() {
        let _ = writeln!(o, "\nNotes");
        for n in &e.notes {
            let _ = writeln!(o, "  - {n}");
        }
    }
    o
}

fn node_text(o: &mut String, n: &RayNode, ind: &str, title: &str, counter: &mut usize) {
    let _ = writeln!(
        o,
        "\n{ind}{title}: {} ray, depth {}: p(λ) = {}",
        n.role.label(),
        n.depth,
        ray_text(&n.ray)
    );
    if n.truncated {
        let _ = writeln!(
            o,
            "{ind}  (not broken down: the ray budget is spent) colour {}",
            vec_text(&n.colour)
        );
        return;
    }
    let _ = writeln!(
        o,
        "{ind}  hits count for λ > {}; tested against {} of {} objects",
        num(n.lambda_min),
        n.tested,
        n.objects
    );
    for t in &n.tests {
        object_text(o, t, &format!("{ind}  "));
    }
    let Some(h) = &n.hit else {
        let _ = writeln!(o, "{ind}  No hit: the background {}", vec_text(&n.colour));
        return;
    };
    let part = if h.part == h.shape {
        String::new()
    } else {
        format!(", {}", h.part)
    };
    let _ = writeln!(
        o,
        "{ind}  Hit: {} ({}{part}) at λ = {}",
        name_text(h.object, &h.name),
        h.shape,
        num(h.lambda)
    );
    let _ = writeln!(
        o,
        "{ind}    object-space point {}",
        vec_text(&h.object_point)
    );
    let _ = writeln!(o, "{ind}    world point        {}", vec_text(&h.point));
    let _ = writeln!(
        o,
        "{ind}    normal             {} ({})",
        vec_text(&h.normal),
        if h.front {
            "the ray arrives from its outside"
        } else {
            "the ray does not arrive from its outside: n · d ≥ 0"
        }
    );
    let Some(s) = &n.shading else { return };
    let m = &s.material;
    let _ = writeln!(
        o,
        "{ind}  Shading: n = {}, v = {}",
        vec_text(&s.n),
        vec_text(&s.v)
    );
    let _ = writeln!(
        o,
        "{ind}    material: ambient {}, diffuse {}, specular {}, shininess {}, mirror {}, transmission {}, ior {}",
        vec_text(&m.ambient),
        vec_text(&m.diffuse),
        vec_text(&m.specular),
        num(m.shininess),
        vec_text(&m.mirror),
        vec_text(&m.transmission),
        num(m.ior)
    );
    let _ = writeln!(o, "{ind}    ambient ⊙ m.ambient = {}", vec_text(&s.ambient));
    for l in &s.lights {
        let _ = writeln!(
            o,
            "{ind}    light {} ({}, colour {}): shadow ray {} for λ in ({}, {})",
            l.light,
            l.kind,
            vec_text(&l.colour),
            ray_text(&l.shadow_ray),
            num(l.lambda_min),
            l.lambda_max.map_or("∞".into(), num)
        );
        if l.outside_cone {
            let _ = writeln!(o, "{ind}      outside the spot's cone: no light");
        } else if l.blocked {
            match &l.blocker {
                Some(b) => {
                    let _ = writeln!(
                        o,
                        "{ind}      blocked by {} at λ = {}: no diffuse or specular",
                        name_text(b.object, &b.name),
                        num(b.lambda)
                    );
                }
                None => {
                    let _ = writeln!(o, "{ind}      blocked: no diffuse or specular");
                }
            }
        } else {
            let _ = writeln!(
                o,
                "{ind}      not blocked: l = {}, n·l = {}, r·v = {}",
                vec_text(&l.l),
                num(l.n_dot_l),
                num(l.r_dot_v)
            );
            let _ = writeln!(
                o,
                "{ind}      diffuse {}, specular {}",
                vec_text(&l.diffuse),
                vec_text(&l.specular)
            );
        }
    }
    if let Some(why) = &s.no_secondary {
        let _ = writeln!(o, "{ind}    no reflected or refracted ray: {why}");
    }
    let child_ind = format!("{ind}    ");
    for (label, sec) in [("mirror", &s.reflection), ("transmission", &s.refraction)] {
        if let Some(sec) = sec {
            *counter += 1;
            let title = format!("Ray {counter}");
            node_text(o, &sec.ray, &child_ind, &title, counter);
            let _ = writeln!(
                o,
                "{child_ind}  contribution: {label} {} ⊙ {} = {}",
                vec_text(&sec.coefficient),
                vec_text(&sec.ray.colour),
                vec_text(&sec.contribution)
            );
        }
    }
    let _ = writeln!(o, "{ind}  colour of this ray: {}", vec_text(&n.colour));
}

fn object_text(o: &mut String, t: &ObjectTest, ind: &str) {
    let _ = writeln!(o, "{ind}{} ({})", name_text(t.object, &t.name), t.shape);
    o.push_str(&matrix_text(
        &t.inverse_transform,
        &format!("{ind}  "),
        "T⁻¹ = ",
    ));
    let _ = writeln!(o, "{ind}  ray in object space: {}", ray_text(&t.object_ray));
    if t.linear_side {
        let _ = writeln!(
            o,
            "{ind}  side: a = 0 (parallel to a generator line), the equation is linear"
        );
    }
    for q in &t.quadratics {
        let _ = writeln!(
            o,
            "{ind}  {}: a = {}, b = {}, c = {}; discriminant b² − 4ac = {}",
            q.surface,
            num(q.a),
            num(q.b),
            num(q.c),
            num(q.discriminant)
        );
        let verdict = if q.discriminant < 0.0 {
            "negative: no real root, a miss"
        } else if q.roots.len() == 1 {
            "zero: one root, a tangent"
        } else if q.roots.is_empty() {
            "a = 0: no quadratic to solve"
        } else {
            "positive: two roots"
        };
        let _ = writeln!(o, "{ind}    discriminant {verdict}");
        for r in &q.roots {
            let _ = writeln!(
                o,
                "{ind}    λ = {} at {}: {}",
                num(r.lambda),
                vec_text(&r.point),
                r.why
            );
        }
    }
    for f in &t.faces {
        let face = match f.face {
            "top" | "bottom" => format!("{} cap", f.face),
            l if l.starts_with(['+', '-']) => format!("face {l}"),
            l => l.to_owned(),
        };
        match (f.lambda, f.point) {
            (Some(l), Some(p)) => {
                let _ = writeln!(
                    o,
                    "{ind}  {face}: λ = {}, point {}: {}",
                    num(l),
                    vec_text(&p),
                    f.why
                );
            }
            _ => {
                let _ = writeln!(o, "{ind}  {face}: {}", f.why);
            }
        }
    }
    for tr in &t.triangles {
        match (tr.barycentric, tr.lambda) {
            (Some([a, b]), Some(l)) => {
                let _ = writeln!(
                    o,
                    "{ind}  triangle {}: u = {}, v = {}, λ = {}: {}",
                    tr.triangle,
                    num(a),
                    num(b),
                    num(l),
                    tr.why
                );
            }
            _ => {
                let _ = writeln!(o, "{ind}  triangle {}: {}", tr.triangle, tr.why);
            }
        }
    }
    if t.triangles_unlisted > 0 {
        let _ = writeln!(
            o,
            "{ind}  … {} more triangle tests, none the first hit",
            t.triangles_unlisted
        );
    }
    if matches!(t.shape, "mesh") && t.triangles.is_empty() {
        let _ = writeln!(
            o,
            "{ind}  no triangle tested: the ray misses the mesh's bounding boxes"
        );
    }
    match (t.lambda, &t.part) {
        (Some(l), Some(part)) => {
            let _ = writeln!(
                o,
                "{ind}  → first hit λ = {} ({part}){}",
                num(l),
                if t.chosen { ", the ray's closest" } else { "" }
            );
        }
        _ => {
            let _ = writeln!(o, "{ind}  → no hit");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{ColourKernel, Kernel};
    use crate::scene::{Limits, parse};
    use std::sync::Arc;

    fn renderer(name: &str) -> Renderer {
        let path = format!("{}/scenes/{name}", env!("CARGO_MANIFEST_DIR"));
        let bytes = std::fs::read(path).unwrap();
        Renderer::new(Arc::new(parse(&bytes, &Limits::NONE).unwrap()))
    }

    #[test]
    fn lecture_pixel_2_2_value_by_value() {
        let r = renderer("lecture.json");
        let e = explain(&r, 2, 2, &ExplainOptions::default());
        assert_eq!(e.primary.camera.origin, [0.0, 0.0, 0.0, 1.0]);
        assert_eq!(e.primary.camera.direction, [0.0, 0.0, 1.0, 0.0]);
        assert_eq!(e.primary.world, e.primary.camera);
        assert_eq!(e.candidates, Candidates::All);
        let t = &e.tree.tests[0];
        assert_eq!(
            t.inverse_transform,
            [
                [1.0, 0.0, 0.0, -1.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, -2.0],
                [0.0, 0.0, 0.0, 1.0]
            ]
        );
        assert_eq!(t.object_ray.origin, [-1.0, 0.0, -2.0, 1.0]);
        assert_eq!(t.object_ray.direction, [0.0, 0.0, 1.0, 0.0]);
        let q = &t.quadratics[0];
        assert_eq!((q.a, q.b, q.c, q.discriminant), (1.0, -4.0, 4.0, 0.0));
        assert_eq!(q.roots.len(), 1);
        assert_eq!(q.roots[0].lambda, 2.0);
        assert!(q.roots[0].counts);
        assert!(t.chosen);
        let h = e.tree.hit.as_ref().unwrap();
        assert_eq!(h.lambda, 2.0);
        assert_eq!(h.object_point, [-1.0, 0.0, 0.0, 1.0]);
        assert_eq!(h.point, [0.0, 0.0, 2.0, 1.0]);
        assert_eq!(h.normal, [-1.0, 0.0, 0.0, 0.0]);
        assert_eq!(h.name.as_deref(), Some("ball"));
    }

    #[test]
    fn lecture_text_shows_the_worked_example() {
        let r = renderer("lecture.json");
        let text = to_text(&explain(&r, 2, 2, &ExplainOptions::default()));
        for want in [
            "p(λ) = [0, 0, 0, 1] + λ [0, 0, 1, 0]",
            "T⁻¹ = [ 1  0  0  -1 ]",
            "      [ 0  0  1  -2 ]",
            "discriminant zero: one root, a tangent",
            "ray in object space: [-1, 0, -2, 1] + λ [0, 0, 1, 0]",
            "a = 1, b = -4, c = 4; discriminant b² − 4ac = 0",
            "λ = 2 at [-1, 0, 0, 1]: the object's first hit",
            "object-space point [-1, 0, 0, 1]",
        ] {
            assert!(text.contains(want), "missing {want:?} in\n{text}");
        }
    }

    /// The tree's colour is the tracer's, and the final 8-bit colour is the PNG's.
    #[test]
    fn showcase_colours_match_the_renderer() {
        let r = renderer("showcase.json");
        let shader = Shader {
            scene: &r.scene,
            world: &r.world,
        };
        // Floor, mirror ball, glass ball, small ball, cube, column, cone, backdrop, gem, slab,
        // sky and corners.
        for (u, v) in [
            (512, 700),
            (380, 380),
            (640, 470),
            (470, 500),
            (800, 380),
            (560, 300),
            (200, 400),
            (170, 260),
            (270, 409),
            (743, 477),
            (512, 20),
            (0, 0),
            (1023, 767),
        ] {
            let e = explain(&r, u, v, &ExplainOptions::default());
            let centre = shader.trace(
                &r.camera.pixel_centre(u, v),
                0,
                PRIMARY_LAMBDA_MIN,
                &mut RayCount(0),
            );
            assert_eq!(e.tree.colour, centre.to_array(), "pixel ({u}, {v})");
            let rendered = ColourKernel(&r).pixel(u, v, &mut 0);
            assert_eq!(e.colour.rgb8, rendered, "pixel ({u}, {v})");
            assert_eq!(e.colour.samples.len(), 4);
        }
    }

    /// Every pixel of small scenes of every shape: the tree sums exactly as the tracer.
    #[test]
    fn every_shape_tree_sums_like_the_tracer() {
        for name in [
            "sphere.json",
            "cube.json",
            "plane.json",
            "disk.json",
            "cylinder.json",
            "cone.json",
            "mesh.json",
        ] {
            let r = renderer(name);
            let shader = Shader {
                scene: &r.scene,
                world: &r.world,
            };
            for v in (0..r.scene.height).step_by(7) {
                for u in (0..r.scene.width).step_by(7) {
                    let e = explain(&r, u, v, &ExplainOptions::default());
                    let c = shader.trace(
                        &r.camera.pixel_centre(u, v),
                        0,
                        PRIMARY_LAMBDA_MIN,
                        &mut RayCount(0),
                    );
                    assert_eq!(e.tree.colour, c.to_array(), "{name} ({u}, {v})");
                    let chosen = e.tree.tests.iter().filter(|t| t.chosen).count();
                    assert_eq!(chosen, e.tree.hit.is_some() as usize, "{name} ({u}, {v})");
                    if let Some(h) = &e.tree.hit {
                        let t = e.tree.tests.iter().find(|t| t.chosen).unwrap();
                        assert_eq!(t.lambda, Some(h.lambda), "{name} ({u}, {v})");
                    }
                }
            }
        }
    }

    #[test]
    fn bvh_candidates_keep_the_chosen_hit() {
        let r = renderer("showcase.json");
        let opts = ExplainOptions {
            candidates: Candidates::Bvh,
            ..Default::default()
        };
        let e = explain(&r, 380, 380, &opts);
        assert_eq!(e.candidates, Candidates::Bvh);
        assert!(e.tree.tested < e.tree.objects);
        assert!(e.tree.tests.iter().any(|t| t.chosen));
    }

    #[test]
    fn ray_budget_truncates_but_keeps_the_colour() {
        let r = renderer("showcase.json");
        let full = explain(&r, 640, 470, &ExplainOptions::default());
        let cut = explain(
            &r,
            640,
            470,
            &ExplainOptions {
                max_rays: 1,
                ..Default::default()
            },
        );
        assert_eq!(full.tree.colour, cut.tree.colour);
        assert!(cut.notes.iter().any(|n| n.contains("first 1 rays")));
    }

    #[test]
    fn outside_pixels_are_refused_by_check() {
        let r = renderer("lecture.json");
        assert!(check_pixel(&r, 4, 4).is_ok());
        assert!(check_pixel(&r, 5, 0).is_err());
    }

    #[test]
    fn numbers_print_as_the_lecture_writes_them() {
        assert_eq!(num(-0.0), "0");
        assert_eq!(num(2.0), "2");
        assert_eq!(num(-4.0), "-4");
        assert_eq!(num(0.1 + 0.2), "0.30000000000000004");
        assert_eq!(num(1e-9), "1e-9");
    }
}
