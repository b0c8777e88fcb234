//! Whitted ray tracing with the Phong model (`docs/spec/shading.md`).
//!
//! ```text
//! colour = ambient ⊙ m.ambient
//!        + Σ unshadowed lights L.colour ⊙ (m.diffuse·max(0, n·l) + m.specular·max(0, r·v)^shininess)
//!        + m.mirror ⊙ trace(reflected) + m.transmission ⊙ trace(refracted)
//! ```
//!
//! Secondary rays (shadow, reflection, refraction) start off the surface: the hit point
//! moved by [`surface_offset`] along the normal, to the side the ray leaves by, and they
//! count hits with `λ > 1e-9`. Reflected and refracted directions are unit vectors; a
//! shadow ray toward a point light runs from that origin to the light at `λ = 1`.
//!
//! The recursion is written once, in [`Shader::trace_probed`], generic over a
//! [`ShadingProbe`] as the shape tests are over [`Probe`](crate::geometry::Probe): the
//! renderer's `()` compiles to the bare tracer, and explaining a pixel passes a recorder
//! that sees every value the tracer computes. It is generic over [`Conventions`] too: the
//! renderer's [`Lecture`] is the specification, and diagnosing a submission renders the
//! classic mistakes of the course with other instantiations (`crate::grade::diagnose`).

use std::cell::Cell;

use glam::DVec3;

use crate::geometry::bounds::lanes_of;
use crate::geometry::{Hit, Ray, Rays8, ShadowHint, Surface, Transform, World};
use crate::scene::{Light, Material, Scene};

mod light;

pub use light::{LightTerm, light_term_as, surface_offset, unshadowed_light_term};

/// Smallest `λ` of a secondary ray's hit.
pub const SECONDARY_LAMBDA_MIN: f64 = 1e-9;

/// How a tracer follows the course's conventions: [`Lecture`] follows them all, and each
/// classic mistake that diagnosis renders breaks one. Every choice is an associated
/// constant, so each instantiation is compiled on its own and in the lecture's every test
/// of a constant folds away: the renderer's code is the tracer without the switches.
pub trait Conventions: Sync {
    /// What is added to a pixel's (or a sample cell's) index to reach the image point its
    /// ray passes through: ½, the centre (`docs/spec/camera.md`, The primary ray).
    const PIXEL_OFFSET: f64 = 0.5;
    /// Whether shadow rays are traced (`shading.md`, Shadows); when not, nothing blocks.
    const SHADOWS: bool = true;
    /// The recursion depths (bit `k` for depth `k`) at which every light is blocked
    /// wherever it would add something: what a shadow ray from the surface itself, not
    /// moved off it, meets at a part of the lit points chosen by rounding (shadow acne,
    /// `shading.md`, Secondary rays).
    const SELF_SHADOWED_DEPTHS: u32 = 0;
    /// Whether the ambient term is added.
    const AMBIENT: bool = true;
    /// Whether the specular term is added.
    const SPECULAR: bool = true;
    /// Whether the specular term is Blinn–Phong's `(n·h)^shininess` instead of Phong's.
    const BLINN_PHONG: bool = false;
    /// Whether mirror rays are traced.
    const REFLECTION: bool = true;
    /// Whether refracted rays are traced.
    const REFRACTION: bool = true;
    /// Whether Snell's ratio is inverted (`ior` entering, `1/ior` leaving).
    const INVERTED_ETA: bool = false;
    /// Added to `max_depth` where the recursion stops.
    const EXTRA_DEPTH: i64 = 0;
    /// Whether the world normal is carried by `(T⁻¹)ᵀ` (else by `T` itself).
    const INVERSE_TRANSPOSE: bool = true;
    /// Whether the world normal is normalised after it is carried.
    const NORMALISED: bool = true;
    /// Whether hit data gives `λ` along the normalised direction `d/|d|` (a distance)
    /// instead of along `d` (`docs/spec/camera.md`, The primary ray).
    const UNIT_DIRECTION_LAMBDA: bool = false;
}

/// The course's conventions, as the specification writes them: what the renderer uses.
#[derive(Debug, Clone, Copy, Default)]
pub struct Lecture;

impl Conventions for Lecture {}

/// The hit's normal as a tracer of conventions `C` computes it: the world normal carried
/// by `T` instead of `(T⁻¹)ᵀ`, or not normalised. `n_world ∝ (T⁻¹)ᵀ n_object` gives
/// `n_object ∝ Tᵀ n_world`, so the object's normal is recovered from the surface record
/// and nothing in the geometry's hot path changes. `t` is the hit object's
/// `world_from_object`.
#[inline(always)]
pub fn conventional_surface<C: Conventions>(t: &Transform, s: Surface) -> Surface {
    if C::INVERSE_TRANSPOSE && C::NORMALISED {
        return s;
    }
    let m = t.forward.matrix3;
    let n_object = m.transpose().mul_vec3(s.normal).normalize();
    let carried = if C::INVERSE_TRANSPOSE {
        t.inverse.matrix3.transpose().mul_vec3(n_object)
    } else {
        m.mul_vec3(n_object)
    };
    Surface {
        normal: if C::NORMALISED {
            carried.normalize()
        } else {
            carried
        },
        ..s
    }
}

/// Whether hit data under conventions `C` is the world's record of a hit unchanged
/// ([`conventional_hit`] gives it back as it is), as under the lecture's: a caller may
/// then leave a record where the world wrote it.
pub const fn hit_as_found<C: Conventions>() -> bool {
    C::INVERSE_TRANSPOSE && C::NORMALISED && !C::UNIT_DIRECTION_LAMBDA
}

/// A primary ray's hit as hit data written under conventions `C` gives it: its normal as
/// [`conventional_surface`] makes it, `λ` along `d/|d|` where `C` measures it so.
#[inline(always)]
pub fn conventional_hit<C: Conventions>(t: &Transform, ray: &Ray, s: Surface) -> Surface {
    if hit_as_found::<C>() {
        return s;
    }
    let s = conventional_surface::<C>(t, s);
    if C::UNIT_DIRECTION_LAMBDA {
        Surface {
            lambda: s.lambda * ray.dir.length(),
            ..s
        }
    } else {
        s
    }
}

/// Counts the rays a pixel costs (primary and secondary).
#[derive(Debug, Default, Clone, Copy)]
pub struct RayCount(pub u64);

/// The normal turned to face the incoming ray.
#[inline]
pub fn facing_normal(s: &Surface, dir: DVec3) -> DVec3 {
    if s.normal.dot(dir) < 0.0 {
        s.normal
    } else {
        -s.normal
    }
}

/// The mirror ray at the surface point `point` hit along `dir`, `n` the normal facing
/// the ray.
// Always inlined, as `unshadowed_light_term` is.
#[inline(always)]
pub fn reflected_ray(point: DVec3, n: DVec3, dir: DVec3) -> Ray {
    mirror_ray(point, n, dir.normalize())
}

/// [`reflected_ray`] of the ray's unit direction `i`, found by the caller.
#[inline(always)]
fn mirror_ray(point: DVec3, n: DVec3, i: DVec3) -> Ray {
    let outside = point + n * surface_offset(point);
    let cos_i = -n.dot(i);
    Ray::new(outside, i + 2.0 * cos_i * n)
}

/// The refracted ray at the surface point `point` hit along `dir` (on the outside of
/// the surface where `front`), with `ior` the material's index (entering from air
/// when the ray meets the outside), under conventions `C`; `None` under total
/// internal reflection (where the refraction's weight goes to the mirror ray). Apart
/// from [`reflected_ray`], so that a surface that only reflects (most mirrors) never
/// pays for this one's square roots.
#[inline(always)]
pub fn refracted_ray_as<C: Conventions>(
    (point, front): (DVec3, bool),
    n: DVec3,
    dir: DVec3,
    ior: f64,
) -> Option<Ray> {
    let i = dir.normalize();
    let inside = point - n * surface_offset(point);
    let cos_i = -n.dot(i);
    let eta = if front != C::INVERTED_ETA {
        1.0 / ior
    } else {
        ior
    };
    let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
    if k < 0.0 {
        None
    } else {
        let t = eta * i + (eta * cos_i - k.sqrt()) * n;
        Some(Ray::new(inside, t.normalize()))
    }
}

/// Which secondary ray a surface sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Branch {
    /// The mirror ray, weighted by `m.mirror`.
    Reflection,
    /// The refracted ray (or its total internal reflection), weighted by `m.transmission`.
    Refraction,
}

/// Why a hit sends no secondary rays.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoSecondary {
    /// The material has neither `mirror` nor `transmission`.
    Material,
    /// The ray is already at the scene's `max_depth`.
    MaxDepth,
}

/// Receives every value [`Shader::trace_probed`] computes, in the order it computes them.
/// The renderer passes `()`, whose methods are empty and compile away; explaining a pixel
/// passes a recorder, so the explanation is the tracer's own computation, not a copy.
///
/// Each ray gets its own probe: the one a secondary ray is traced with comes from
/// [`ShadingProbe::secondary`] and is handed back through [`ShadingProbe::secondary_done`].
pub trait ShadingProbe: Sized {
    /// A ray is about to be traced at recursion `depth`, its hits counting for `λ > t_min`.
    #[inline(always)]
    fn ray(&mut self, _ray: &Ray, _depth: u32, _t_min: f64) {}
    /// The ray's closest hit was found, or none (then it returns the background).
    #[inline(always)]
    fn closest(&mut self, _hit: Option<&Hit>) {}
    /// The hit's surface record, its normal turned to face the ray, its material and the
    /// ambient term `ambient ⊙ m.ambient` the colour starts from.
    #[inline(always)]
    fn surface(&mut self, _hit: &Hit, _s: &Surface, _n: DVec3, _m: &Material, _ambient: DVec3) {}
    /// Light `index`'s unshadowed terms, and whether its shadow ray was blocked: `None`
    /// when the tracer cast none (outside a spot's cone, or the light would add nothing).
    #[inline(always)]
    fn light(&mut self, _index: usize, _light: &Light, _term: &LightTerm, _blocked: Option<bool>) {}
    /// The hit sends no secondary rays, and why.
    #[inline(always)]
    fn no_secondary(&mut self, _why: NoSecondary) {}
    /// A secondary ray of `branch` is about to be traced (a refraction's ray is the
    /// mirror ray when `total_internal_reflection`): the probe that follows it.
    fn secondary(&mut self, branch: Branch, total_internal_reflection: bool) -> Self;
    /// The secondary ray of `branch` came back with `colour`; `coefficient ⊙ colour` is
    /// the `contribution` added to this ray's colour.
    #[inline(always)]
    fn secondary_done(
        &mut self,
        _branch: Branch,
        _child: Self,
        _coefficient: DVec3,
        _colour: DVec3,
        _contribution: DVec3,
    ) {
    }
}

impl ShadingProbe for () {
    #[inline(always)]
    fn secondary(&mut self, _branch: Branch, _total_internal_reflection: bool) {}
}

/// A hit ready to shade, as shading reads its surface record: the point, whether the
/// ray met the outside of the surface, the normal facing the ray, the material. Not
/// the whole record: a packet keeps its eight hits' until their secondary rays are
/// made, and kept whole, each record's object-space point was computed for nothing
/// (a flat part's normal does not need it).
struct HitPoint<'a> {
    point: DVec3,
    front: bool,
    n: DVec3,
    m: &'a Material,
}

/// A secondary ray a hit sends: its branch, whether it is a total internal reflection
/// (a refraction's weight carried by the mirror ray), its weight, the ray.
#[derive(Clone, Copy)]
struct Secondary {
    branch: Branch,
    total_internal_reflection: bool,
    weight: DVec3,
    ray: Ray,
}

/// One branch's secondary rays of a packet's eight hits (the mirror rays, or the
/// refracted ones): the lanes that send one, and each one's ray and weight.
struct Sent8 {
    lanes: u32,
    rays: [Ray; 8],
    weight: [DVec3; 8],
}

impl Sent8 {
    /// Lane `k`'s secondary rays, as [`Shader::secondaries_as`] gives them, put into
    /// their branches of `packet`. The branches are made when the packet's first ray is
    /// sent (most packets send none: made for each, they cost 1.5 % more instructions
    /// on scenes without mirrors), and each branch is filled with its first ray, so
    /// that the lanes that send none carry a sent ray for the packet's test (filled
    /// with a copy of the primary rays, classic's render took 1.9 % more).
    #[inline(always)]
    fn put(packet: &mut Option<[Option<Sent8>; 2]>, k: usize, next: [Option<Secondary>; 2]) {
        for (b, n) in next.iter().enumerate() {
            if let Some(n) = n {
                let branch = &mut packet.get_or_insert_with(|| [None, None])[b];
                let sent = branch.get_or_insert_with(|| Sent8 {
                    lanes: 0,
                    rays: [n.ray; 8],
                    weight: [DVec3::ZERO; 8],
                });
                sent.lanes |= 1 << k;
                sent.rays[k] = n.ray;
                sent.weight[k] = n.weight;
            }
        }
    }
}

/// Lights whose shadow rays keep a hint ([`World::occluded_hinted`]).
const HINTED_LIGHTS: usize = 8;
/// Recursion depths whose shadow rays keep their own hints.
const HINTED_DEPTHS: usize = 3;

/// A scene and its world, ready to shade rays, one pixel after another (one thread's).
pub struct Shader<'a> {
    /// The scene.
    pub scene: &'a Scene,
    /// Its acceleration structure.
    pub world: &'a World,
    /// `[depth][k]`: the object that blocked the last shadow ray toward light `k` from a
    /// hit at recursion `depth`, if one did. Neighbouring pixels' rays toward a light
    /// are mostly blocked by the same object: tested first, it is then the only test
    /// (render instructions: `cubes-10k` −12 %, `spheres-1k` −6 %, `classic` −3 %).
    /// Each depth keeps its own, so that a mirror's rays, shaded between two pixels'
    /// primary hits, do not replace theirs.
    shadow_hints: [[Cell<ShadowHint>; HINTED_LIGHTS]; HINTED_DEPTHS],
    /// [`Scene::sends_secondaries`], as the renderer found it: where no hit sends a
    /// secondary ray, a packet's hits skip asking each material (render instructions
    /// −1.7 % on spheres-1k).
    secondaries: bool,
}

impl<'a> Shader<'a> {
    /// A shader of `scene`, tracing through `world` (built from it), `secondaries`
    /// its [`Scene::sends_secondaries`] (made once, by
    /// [`Renderer::shader`](crate::render::Renderer::shader)). Pixels shaded by one
    /// shader one after another, neighbours in order, share its hints.
    pub(in crate::render) fn new(
        scene: &'a Scene,
        world: &'a World,
        secondaries: bool,
    ) -> Shader<'a> {
        Shader {
            scene,
            world,
            shadow_hints: Default::default(),
            secondaries,
        }
    }

    /// [`World::occluded`] of light `k`'s shadow ray `t` from a hit at `depth`, with
    /// the hint this shader keeps for them, if it keeps one.
    #[inline(always)]
    fn light_blocked(&self, k: usize, depth: u32, ray: &Ray, t_max: f64) -> bool {
        match self.shadow_hints.get(depth as usize).and_then(|h| h.get(k)) {
            Some(hint) => {
                let mut h = hint.get();
                let blocked = self
                    .world
                    .occluded_hinted(ray, SECONDARY_LAMBDA_MIN, t_max, &mut h);
                hint.set(h);
                blocked
            }
            None => self.world.occluded(ray, SECONDARY_LAMBDA_MIN, t_max),
        }
    }

    /// [`Shader::light_blocked`] for light `k`'s shadow rays `rays` of the lanes `cast`
    /// from a packet's hits at `depth`, each within `t_max[lane]`, one after another
    /// ([`World::occluded_each`]): the bit set of those blocked.
    #[inline(always)]
    fn lights_blocked(
        &self,
        k: usize,
        depth: u32,
        rays: &Rays8,
        cast: u32,
        t_max: &[f64; 8],
    ) -> u32 {
        let kept = self.shadow_hints.get(depth as usize).and_then(|h| h.get(k));
        // A light without a hint kept has one for the packet's rays alone.
        let mut hint = kept.map(Cell::get).unwrap_or_default();
        let blocked =
            (self.world).occluded_each(rays, cast, SECONDARY_LAMBDA_MIN, t_max, &mut hint);
        if let Some(kept) = kept {
            kept.set(hint);
        }
        blocked
    }
}

impl Shader<'_> {
    /// The colour seen along `ray`, a ray at recursion `depth`.
    #[inline]
    pub fn trace(&self, ray: &Ray, depth: u32, t_min: f64, rays: &mut RayCount) -> DVec3 {
        self.trace_probed(ray, depth, t_min, rays, &mut ())
    }

    /// [`Shader::trace`], reporting every step to `probe`.
    #[inline]
    pub fn trace_probed<P: ShadingProbe>(
        &self,
        ray: &Ray,
        depth: u32,
        t_min: f64,
        rays: &mut RayCount,
        probe: &mut P,
    ) -> DVec3 {
        self.trace_as::<P, Lecture>(ray, depth, t_min, rays, probe)
    }

    /// [`Shader::trace_probed`] under conventions `C`.
    pub fn trace_as<P: ShadingProbe, C: Conventions>(
        &self,
        ray: &Ray,
        depth: u32,
        t_min: f64,
        rays: &mut RayCount,
        probe: &mut P,
    ) -> DVec3 {
        probe.ray(ray, depth, t_min);
        let closest = self.world.closest(ray, t_min, f64::INFINITY);
        self.shade_as::<P, C>(ray, depth, closest, rays, probe)
    }

    /// The colour `ray` brings back given its first hit `closest` (found by the caller,
    /// e.g. for a packet of primary rays, exactly as [`Shader::trace_as`] finds it):
    /// everything [`Shader::trace_as`] does after its search, counting `ray` first.
    // Always inlined, the hit's shading a call of its own: most of a mirror's rays
    // miss, and a call for each cost more than the miss (the background) itself.
    #[inline(always)]
    pub fn shade_as<P: ShadingProbe, C: Conventions>(
        &self,
        ray: &Ray,
        depth: u32,
        closest: Option<Hit>,
        rays: &mut RayCount,
        probe: &mut P,
    ) -> DVec3 {
        rays.0 += 1;
        probe.closest(closest.as_ref());
        match closest {
            Some(hit) => self.shade_hit_as::<P, C>(ray, depth, hit, rays, probe),
            None => self.scene.background,
        }
    }

    /// [`Shader::shade_as`] of a ray that hit something, once it is counted.
    fn shade_hit_as<P: ShadingProbe, C: Conventions>(
        &self,
        ray: &Ray,
        depth: u32,
        hit: Hit,
        rays: &mut RayCount,
        probe: &mut P,
    ) -> DVec3 {
        let (s, at, ambient) = self.hit_point_as::<C>(ray, &hit, false);
        probe.surface(&hit, &s, at.n, at.m, ambient);
        let c = self.add_lights_as::<P, C>(ray, depth, &at, ambient, rays, probe);
        self.add_secondaries_as::<P, C>(ray, depth, &at, c, rays, probe)
    }

    /// `c`, the colour of a hit of `ray` at `depth` so far, with each light's terms
    /// added where its shadow ray is not blocked, in the order of the scene's lights.
    #[inline(always)]
    fn add_lights_as<P: ShadingProbe, C: Conventions>(
        &self,
        ray: &Ray,
        depth: u32,
        at: &HitPoint,
        mut c: DVec3,
        rays: &mut RayCount,
        probe: &mut P,
    ) -> DVec3 {
        for (k, light) in self.scene.lights.iter().enumerate() {
            let t = light_term_as::<C>(light, at.point, at.n, ray.dir, at.m);
            if !t.casts_shadow_ray() {
                probe.light(k, light, &t, None);
                continue;
            }
            rays.0 += C::SHADOWS as u64;
            let blocked = (C::SELF_SHADOWED_DEPTHS != 0
                && (C::SELF_SHADOWED_DEPTHS >> depth.min(31)) & 1 == 1)
                || C::SHADOWS && self.light_blocked(k, depth, &t.shadow_ray, t.shadow_t_max);
            probe.light(k, light, &t, Some(blocked));
            if !blocked {
                c += t.lit();
            }
        }
        c
    }

    /// [`Shader::shade_as`] for eight primary rays (`depth` 0) and their first hits, under
    /// the lecture's conventions with nothing recorded: each colour bit for bit, each
    /// pixel's terms added in the order `shade_as` adds them. The pixels' secondary rays
    /// of each branch are traced together ([`World::closest8`]), as the primary rays
    /// were: a mirror's rays from neighbouring pixels, a flat mirror's above all, take
    /// much the same path. What they hit is shaded together as well, the same way, and
    /// so on down to `max_depth` (one ray alone is traced and shaded alone): shaded ray
    /// by ray, `classic`'s mirror hits took 3.9 % more render instructions.
    ///
    /// Each light's terms are computed for the eight hits at once, in SIMD lanes
    /// (`light::light8`): a term's square roots and division wait on each other, and
    /// a pixel at a time the wait was the hottest spot of `classic`'s render. Where the
    /// world traces shadow rays as packets ([`World::traces_shadow_packets`]), a
    /// light's shadow rays are traced together too ([`World::occluded8`]); elsewhere
    /// one after another in one call, with its light's hint at that depth
    /// ([`World::occluded_each`]).
    pub fn shade8(
        &self,
        primary: &[Ray; 8],
        hits: [Option<Hit>; 8],
        rays: &mut RayCount,
    ) -> [DVec3; 8] {
        self.shade_lanes::<true>(primary, hits, 0xff, 0, rays)
    }

    /// [`Shader::shade8`] of the rays `traced` of `lanes` at `depth` and their hits
    /// (`None` in the other lanes): primary rays (`PRIMARY`, at depth 0), or a packet's
    /// secondary rays, deeper. Each lane's colour is what [`Shader::shade_as`] gives its
    /// ray, bit for bit.
    fn shade_lanes<const PRIMARY: bool>(
        &self,
        traced: &[Ray; 8],
        hits: [Option<Hit>; 8],
        lanes: u32,
        depth: u32,
        rays: &mut RayCount,
    ) -> [DVec3; 8] {
        let (lanes, depth) = if PRIMARY { (0xff, 0) } else { (lanes, depth) };
        rays.0 += u64::from(lanes.count_ones());
        let mut c = [self.scene.background; 8];
        if hits.iter().all(Option::is_none) {
            // Sky: the background, and no light to look at.
            return c;
        }
        let mut next = None;
        // Filled in place: made by `array::from_fn` with their records, the eight
        // records (120 bytes each) were copied once more. Its `None`s are made by
        // `array::from_fn` too: `[const { None }; 8]` compiled to a call to `memset`
        // of all 960 bytes (render instructions −0.6 % on classic and spheres-1k).
        let mut at: [Option<HitPoint>; 8] = std::array::from_fn(|_| None);
        for (k, hit) in hits.iter().enumerate() {
            if let Some(hit) = hit {
                let (_, point, ambient) = self.hit_point_as::<Lecture>(&traced[k], hit, PRIMARY);
                (at[k], c[k]) = (Some(point), ambient);
            }
        }
        let mut hits8 = light::Hits8::EMPTY;
        hits8.fill(|k| at[k].as_ref().map(|a| (a.point, a.n, a.m, traced[k].dir)));
        let packets = self.world.traces_shadow_packets();
        for (j, light) in self.scene.lights.iter().enumerate() {
            let t = light::light8(&hits8, light);
            rays.0 += u64::from(t.cast.count_ones());
            let blocked = if packets {
                self.world
                    .occluded8(&t.shadow, t.cast, SECONDARY_LAMBDA_MIN, &t.t_max)
            } else {
                self.lights_blocked(j, depth, &t.shadow, t.cast, &t.t_max)
            };
            for k in lanes_of(t.cast & !blocked) {
                c[k] += t.lit(k);
            }
        }
        if self.secondaries {
            for (k, at) in at.iter().enumerate() {
                if let Some(at) = at {
                    // The unit direction the lights' terms took `v` from: found again,
                    // its square root and division were the most of a mirror ray's
                    // wait.
                    let mirror = || mirror_ray(at.point, at.n, hits8.unit_dir(k));
                    let sends =
                        self.secondaries_as::<(), Lecture>(&traced[k], depth, at, mirror, &mut ());
                    Sent8::put(&mut next, k, sends);
                }
            }
        }
        match &next {
            Some(next) => self.add_secondaries8(next, depth, c, rays),
            None => c,
        }
    }

    /// `c`, the colours of eight hits at `depth` so far, with what their secondary
    /// rays `next` add: each branch's rays traced and shaded as a packet where two or
    /// more pixels send one, the reflections' before the refractions', as
    /// [`Shader::add_secondaries_as`] adds them.
    #[inline(always)]
    fn add_secondaries8(
        &self,
        next: &[Option<Sent8>; 2],
        depth: u32,
        mut c: [DVec3; 8],
        rays: &mut RayCount,
    ) -> [DVec3; 8] {
        for sent in next.iter().flatten() {
            let first = sent.lanes.trailing_zeros() as usize;
            if sent.lanes == 1 << first {
                // One ray: traced alone.
                let ray = &sent.rays[first];
                let colour = self.trace_as::<(), Lecture>(
                    ray,
                    depth + 1,
                    SECONDARY_LAMBDA_MIN,
                    rays,
                    &mut (),
                );
                c[first] += sent.weight[first] * colour;
                continue;
            }
            let hits = (self.world).closest8(
                &sent.rays,
                false,
                sent.lanes,
                SECONDARY_LAMBDA_MIN,
                f64::INFINITY,
                true,
            );
            let colours = self.shade_lanes::<false>(&sent.rays, hits, sent.lanes, depth + 1, rays);
            for k in lanes_of(sent.lanes) {
                c[k] += sent.weight[k] * colours[k];
            }
        }
        c
    }

    /// What shading a hit of `ray` starts from: its surface record under conventions
    /// `C`, and what shading reads of it with the normal facing the ray and its
    /// material; and the ambient term. `view` says that the caller knows `ray` to be a
    /// primary ray ([`World::view_surface`]).
    #[inline(always)]
    fn hit_point_as<C: Conventions>(
        &self,
        ray: &Ray,
        hit: &Hit,
        view: bool,
    ) -> (Surface, HitPoint<'_>, DVec3) {
        let object = &self.scene.objects[hit.object as usize];
        let found = if view {
            self.world.view_surface(ray, hit)
        } else {
            self.world.surface(ray, hit)
        };
        let s = conventional_surface::<C>(&object.transform, found);
        let m = &self.scene.materials[object.material as usize];
        let n = facing_normal(&s, ray.dir);
        let ambient = if C::AMBIENT {
            self.scene.ambient * m.ambient
        } else {
            DVec3::ZERO
        };
        let at = HitPoint {
            point: s.point,
            front: s.front,
            n,
            m,
        };
        (s, at, ambient)
    }

    /// `c`, the colour of a hit of `ray` at `depth` so far, with what its secondary rays
    /// add (none for a material without `mirror` or `transmission`, or at `max_depth`).
    #[inline(always)]
    fn add_secondaries_as<P: ShadingProbe, C: Conventions>(
        &self,
        ray: &Ray,
        depth: u32,
        at: &HitPoint,
        mut c: DVec3,
        rays: &mut RayCount,
        probe: &mut P,
    ) -> DVec3 {
        let mirror = || reflected_ray(at.point, at.n, ray.dir);
        for next in self
            .secondaries_as::<P, C>(ray, depth, at, mirror, probe)
            .iter()
            .flatten()
        {
            c += self.secondary_as::<P, C>(next, depth, rays, probe);
        }
        c
    }

    /// The secondary rays a hit of `ray` at `depth` sends, in the order their colours
    /// are added: the mirror ray, then the refracted one (none for a material without
    /// `mirror` or `transmission`, or at `max_depth`, which `probe` is told).
    /// `mirror()` is the hit's [`reflected_ray`], as the caller makes it.
    #[inline(always)]
    fn secondaries_as<P: ShadingProbe, C: Conventions>(
        &self,
        ray: &Ray,
        depth: u32,
        at: &HitPoint,
        mirror: impl Fn() -> Ray,
        probe: &mut P,
    ) -> [Option<Secondary>; 2] {
        let (n, m) = (at.n, at.m);
        let mut next = [None; 2];
        if !m.sends_secondaries() {
            probe.no_secondary(NoSecondary::Material);
        } else if if C::EXTRA_DEPTH == 0 {
            depth >= self.scene.max_depth
        } else {
            depth as i64 >= self.scene.max_depth as i64 + C::EXTRA_DEPTH
        } {
            probe.no_secondary(NoSecondary::MaxDepth);
        } else {
            // Each ray is made only for a branch that is traced.
            if C::REFLECTION && m.mirror != DVec3::ZERO {
                next[0] = Some(Secondary {
                    branch: Branch::Reflection,
                    total_internal_reflection: false,
                    weight: m.mirror,
                    ray: mirror(),
                });
            }
            if C::REFRACTION && m.transmission != DVec3::ZERO {
                let refracted = refracted_ray_as::<C>((at.point, at.front), n, ray.dir, m.ior);
                next[1] = Some(Secondary {
                    branch: Branch::Refraction,
                    total_internal_reflection: refracted.is_none(),
                    weight: m.transmission,
                    ray: refracted.unwrap_or_else(mirror),
                });
            }
        }
        next
    }

    /// What the secondary ray `next` of a hit at `depth` adds to its colour.
    #[inline(always)]
    fn secondary_as<P: ShadingProbe, C: Conventions>(
        &self,
        next: &Secondary,
        depth: u32,
        rays: &mut RayCount,
        probe: &mut P,
    ) -> DVec3 {
        let mut child = probe.secondary(next.branch, next.total_internal_reflection);
        let ray = &next.ray;
        let colour = self.trace_as::<P, C>(ray, depth + 1, SECONDARY_LAMBDA_MIN, rays, &mut child);
        let add = next.weight * colour;
        probe.secondary_done(next.branch, child, next.weight, colour, add);
        add
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::ray::PRIMARY_LAMBDA_MIN;
    use crate::render::Renderer;
    use crate::scene::{Limits, parse};
    use std::sync::Arc;

    /// Counts the rays a probe is shown, down the tree.
    #[derive(Default)]
    struct Tally {
        rays: u64,
        shadow_rays: u64,
    }

    impl ShadingProbe for Tally {
        fn ray(&mut self, _ray: &Ray, _depth: u32, _t_min: f64) {
            self.rays += 1;
        }
        fn light(&mut self, _i: usize, _l: &Light, _t: &LightTerm, blocked: Option<bool>) {
            self.shadow_rays += blocked.is_some() as u64;
        }
        fn secondary(&mut self, _branch: Branch, _tir: bool) -> Self {
            Tally::default()
        }
        fn secondary_done(&mut self, _b: Branch, child: Self, k: DVec3, c: DVec3, add: DVec3) {
            assert_eq!(add, k * c);
            self.rays += child.rays;
            self.shadow_rays += child.shadow_rays;
        }
    }

    /// A probe changes nothing the tracer computes, and is shown every ray it casts.
    #[test]
    fn a_probe_sees_every_ray_and_changes_no_colour() {
        let path = format!("{}/scenes/showcase.json", env!("CARGO_MANIFEST_DIR"));
        let bytes = std::fs::read(path).unwrap();
        let r = Renderer::new(Arc::new(parse(&bytes, &Limits::NONE).unwrap()));
        let shader = r.shader();
        for v in (0..r.scene.height).step_by(37) {
            for u in (0..r.scene.width).step_by(37) {
                let ray = r.camera.pixel_centre(u, v);
                let mut plain = RayCount(0);
                let c = shader.trace(&ray, 0, PRIMARY_LAMBDA_MIN, &mut plain);
                let (mut probed, mut tally) = (RayCount(0), Tally::default());
                let p = shader.trace_probed(&ray, 0, PRIMARY_LAMBDA_MIN, &mut probed, &mut tally);
                assert_eq!(
                    c.to_array().map(f64::to_bits),
                    p.to_array().map(f64::to_bits)
                );
                assert_eq!(plain.0, probed.0);
                assert_eq!(tally.rays + tally.shadow_rays, plain.0, "pixel ({u}, {v})");
            }
        }
    }
}
