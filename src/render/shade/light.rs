//! What a light adds at a surface point (`docs/spec/shading.md`): the shadow ray toward
//! it, and the diffuse and specular terms it adds where that ray is not blocked.
//!
//! The formula is written once, generic over the numbers it is computed in
//! ([`Arith`]): one `f64` for a lone hit ([`light_term_as`]), or the eight lanes of a
//! packet's hits ([`light8`]), in vectors of four. Every step is the same IEEE
//! operation in the same order either way (no fused steps; choices, not `f64::max`,
//! whose sign of a zero is the compiler's), so a lane's terms are the lone term's, bit
//! for bit.

use glam::DVec3;

use super::{Conventions, Lecture};
use crate::geometry::arith::{Arith, Eight, Lanes4, One, Portable};
use crate::geometry::bounds::lanes_of;
use crate::geometry::{Ray, Rays8, Surface};
use crate::scene::{Light, Material};

/// `1e-9 · max(1, |p|∞)`: see [`surface_offset`].
#[inline(always)]
fn offset<A: Arith>(a: A, p: [A::N; 3]) -> A::N {
    let [x, y, z] = [a.abs(p[0]), a.abs(p[1]), a.abs(p[2])];
    let yz = a.pick_gt(y, z, y, z);
    let largest = a.pick_gt(x, yz, x, yz);
    let one = a.splat(1.0);
    a.mul(a.splat(1e-9), a.pick_gt(largest, one, largest, one))
}

/// How far off the surface secondary rays start: `1e-9 · max(1, |p|∞)`, far above the
/// rounding error of a hit point in f64 and far below anything visible.
#[inline]
pub fn surface_offset(p: DVec3) -> f64 {
    offset(One, p.to_array())
}

/// A light seen from surface points `p` with normals `n`: the shadow rays' origins
/// (moved off the surface) and directions, their limit, the light's colour, and for a
/// spot light the cosine of each point's angle off its axis with the cone's.
#[allow(clippy::type_complexity)]
#[inline(always)]
fn toward<A: Arith>(
    a: A,
    light: &Light,
    p: [A::N; 3],
    n: [A::N; 3],
) -> ([A::N; 3], [A::N; 3], f64, DVec3, Option<(A::N, f64)>) {
    let origin = a.add3(p, a.scale(n, offset(a, p)));
    match *light {
        Light::Point { position, colour } => {
            let to_light = a.sub3(a.splat3(position), origin);
            (origin, to_light, 1.0, colour, None)
        }
        Light::Directional { direction, colour } => {
            (origin, a.splat3(-direction), f64::INFINITY, colour, None)
        }
        Light::Spot {
            position,
            direction,
            cos_angle,
            colour,
        } => {
            let axis = a.dot(
                a.normalize(a.sub3(p, a.splat3(position))),
                a.splat3(direction),
            );
            let to_light = a.sub3(a.splat3(position), origin);
            (origin, to_light, 1.0, colour, Some((axis, cos_angle)))
        }
    }
}

/// What shading reads of a light: `l`, the unit vector toward it; `n·l`; `r·v`, `r`
/// the mirror image of `l` about `n`; and `max(0, n·l)`.
struct Facing<N> {
    l: [N; 3],
    n_dot_l: N,
    r_dot_v: N,
    lambert: N,
}

/// [`Facing`] of the light along `to_light` at points with normals `n`, seen from `v`.
#[inline(always)]
fn facing<A: Arith>(a: A, to_light: [A::N; 3], n: [A::N; 3], v: [A::N; 3]) -> Facing<A::N> {
    let l = a.normalize(to_light);
    let n_dot_l = a.dot(n, l);
    let r = a.sub3(a.scale(n, a.mul(a.splat(2.0), n_dot_l)), l);
    let zero = a.splat(0.0);
    Facing {
        l,
        n_dot_l,
        r_dot_v: a.dot(r, v),
        lambert: a.pick_gt(n_dot_l, zero, n_dot_l, zero),
    }
}

/// `v = −d/|d|`, the unit vector from a hit back toward the viewer along `d`.
#[inline(always)]
fn toward_viewer(dir: DVec3) -> DVec3 {
    -dir.normalize()
}

/// `max(0, cosine)^shininess`.
#[inline(always)]
fn highlight(cosine: f64, shininess: f64) -> f64 {
    // Where `r·v < 0` the power is of +0, which is +0 for any shininess above 0:
    // nearly half the terms, spared their call to `pow`.
    if cosine < 0.0 && shininess > 0.0 {
        0.0
    } else {
        cosine.max(0.0).powf(shininess)
    }
}

/// What one light contributes at a surface point, for shading and for explaining it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LightTerm {
    /// The shadow ray toward the light (unnormalised toward point lights).
    pub shadow_ray: Ray,
    /// `λ` bound of the shadow ray (1 for point lights: the light itself).
    pub shadow_t_max: f64,
    /// Whether the point lies outside a spot light's cone (then nothing else is computed).
    pub outside_cone: bool,
    /// Whether the shadow ray is blocked.
    pub blocked: bool,
    /// Unit vector to the light.
    pub l: DVec3,
    /// `n · l`.
    pub n_dot_l: f64,
    /// `r · v`, `r` the mirror image of `l` about `n`.
    pub r_dot_v: f64,
    /// `L.colour ⊙ m.diffuse · max(0, n·l)`.
    pub diffuse: DVec3,
    /// `L.colour ⊙ m.specular · max(0, r·v)^shininess`.
    pub specular: DVec3,
}

impl LightTerm {
    /// What the light adds where its shadow ray is not blocked.
    #[inline(always)]
    pub fn lit(&self) -> DVec3 {
        self.diffuse + self.specular
    }

    /// Whether a shadow ray is cast: a light the point lies outside the cone of, or
    /// that would add nothing, needs none.
    #[inline(always)]
    pub fn casts_shadow_ray(&self) -> bool {
        !self.outside_cone && self.lit() != DVec3::ZERO
    }

    /// The terms once the shadow ray's verdict is known: a blocked light adds nothing.
    #[inline]
    pub fn shadowed(mut self, blocked: bool) -> LightTerm {
        self.blocked = blocked;
        if blocked {
            self.diffuse = DVec3::ZERO;
            self.specular = DVec3::ZERO;
        }
        self
    }
}

/// One light's terms as if nothing blocked it; the shadow ray is made, not traced.
// Always inlined: with the tracer generic over its probe, the inliner would otherwise
// leave a call per light and per hit in the render hot path.
#[inline(always)]
pub fn unshadowed_light_term(
    light: &Light,
    s: &Surface,
    n: DVec3,
    dir: DVec3,
    m: &Material,
) -> LightTerm {
    light_term_as::<Lecture>(light, s.point, n, dir, m)
}

/// [`unshadowed_light_term`] under conventions `C`, at the surface point `point`.
#[inline(always)]
pub fn light_term_as<C: Conventions>(
    light: &Light,
    point: DVec3,
    n: DVec3,
    dir: DVec3,
    m: &Material,
) -> LightTerm {
    let normal = n.to_array();
    let (origin, to_light, t_max, colour, cone) = toward(One, light, point.to_array(), normal);
    let outside = cone.is_some_and(|(axis, cos_angle)| One.ge(axis, cos_angle) == 0);
    let mut term = LightTerm {
        shadow_ray: Ray::new(DVec3::from_array(origin), DVec3::from_array(to_light)),
        shadow_t_max: t_max,
        outside_cone: outside,
        blocked: false,
        l: DVec3::ZERO,
        n_dot_l: 0.0,
        r_dot_v: 0.0,
        diffuse: DVec3::ZERO,
        specular: DVec3::ZERO,
    };
    if outside {
        return term;
    }
    let v = toward_viewer(dir);
    let f = facing(One, to_light, normal, v.to_array());
    term.l = DVec3::from_array(f.l);
    term.n_dot_l = f.n_dot_l;
    term.r_dot_v = f.r_dot_v;
    term.diffuse = colour * m.diffuse * f.lambert;
    // `pow` is the costliest step of shading; a black specular needs none.
    if C::SPECULAR && m.specular != DVec3::ZERO {
        let cosine = if C::BLINN_PHONG {
            n.dot((term.l + v).normalize())
        } else {
            f.r_dot_v
        };
        term.specular = colour * m.specular * highlight(cosine, m.shininess);
    }
    term
}

/// What a packet's hits bring to their lights' terms, in lanes: each coordinate's eight
/// numbers together. Lanes without a hit carry a copy of a lane with one.
pub(super) struct Hits8 {
    /// The hit points.
    p: [[f64; 8]; 3],
    /// The normals, turned to face the rays.
    n: [[f64; 8]; 3],
    /// `v = −d/|d|`, toward the viewer.
    v: [[f64; 8]; 3],
    /// The materials' diffuse colours.
    diffuse: [[f64; 8]; 3],
    /// The materials' specular colours.
    specular: [[f64; 8]; 3],
    /// The materials' shininess.
    shininess: [f64; 8],
    /// 1 in the lanes with a hit whose material has a specular colour, 0 in the others:
    /// the choice of the lone term's `+0` is made in lanes, and the lanes that call
    /// `pow` are read from it.
    has_specular: [f64; 8],
    /// The lanes with a hit.
    live: u32,
}

/// A packet lane's hit, as [`Hits8::fill`] takes it: its point, its normal facing the
/// ray, its material, the ray's direction.
pub(super) type HitLane<'a> = (DVec3, DVec3, &'a Material, DVec3);

impl Hits8 {
    /// No lanes yet.
    pub const EMPTY: Hits8 = Hits8 {
        p: [[0.0; 8]; 3],
        n: [[0.0; 8]; 3],
        v: [[0.0; 8]; 3],
        diffuse: [[0.0; 8]; 3],
        specular: [[0.0; 8]; 3],
        shininess: [0.0; 8],
        has_specular: [0.0; 8],
        live: 0,
    };

    /// Fills the lanes of a [`Hits8::EMPTY`] from `hit(k)`, lane `k`'s hit if it has
    /// one. A lane without takes a copy of the first lane with one, which only keeps
    /// its numbers ordinary (no 0/0 in it); a packet without any hit leaves every lane
    /// empty. Filled in place: returned, the 1.1 KB of lanes were copied once more.
    #[inline(always)]
    pub fn fill<'a>(&mut self, hit: impl Fn(usize) -> Option<HitLane<'a>>) {
        let first = (0..8).find(|&k| hit(k).is_some()).unwrap_or(0);
        for k in 0..8 {
            let live = hit(k).is_some();
            if let Some(lane) = hit(if live { k } else { first }) {
                self.put(k, live, lane);
            }
        }
    }

    /// Lane `k`'s ray's unit direction `d/|d|`: `−v`, bit for bit (a negation is
    /// exact).
    #[inline(always)]
    pub fn unit_dir(&self, k: usize) -> DVec3 {
        -DVec3::new(self.v[0][k], self.v[1][k], self.v[2][k])
    }

    /// Puts into lane `k` a hit's point, its normal `n` facing the ray, its material
    /// and the ray's direction: the lane's own hit where `live`, else another's.
    #[inline(always)]
    fn put(&mut self, k: usize, live: bool, (point, n, m, dir): HitLane) {
        let v = toward_viewer(dir);
        for (to, from) in [
            (&mut self.p, point),
            (&mut self.n, n),
            (&mut self.v, v),
            (&mut self.diffuse, m.diffuse),
            (&mut self.specular, m.specular),
        ] {
            (to[0][k], to[1][k], to[2][k]) = (from.x, from.y, from.z);
        }
        self.shininess[k] = m.shininess;
        if live {
            self.live |= 1 << k;
            if m.specular != DVec3::ZERO {
                self.has_specular[k] = 1.0;
            }
        }
    }
}

/// A light's terms for a packet's hits: the lanes that cast a shadow ray (as
/// [`LightTerm::casts_shadow_ray`] says), and for those the ray, its limit and what the
/// light adds where it is not blocked ([`LightTerm::lit`]).
pub(super) struct Lit8 {
    /// The lanes that cast a shadow ray.
    pub cast: u32,
    /// The shadow rays (only those of the lanes of `cast` are cast).
    pub shadow: Rays8,
    /// The rays' limit.
    pub t_max: [f64; 8],
    /// What the light adds at each lane's point, coordinate by coordinate (only the
    /// lanes of `cast` are read): left in the form the lanes compute it, since made
    /// into eight zeroed vectors it cost a call to `memset` a light (1.1 % of
    /// spheres-1k's render instructions).
    lit: [[f64; 8]; 3],
}

impl Lit8 {
    /// What the light adds at lane `k`'s point.
    #[inline(always)]
    pub fn lit(&self, k: usize) -> DVec3 {
        DVec3::new(self.lit[0][k], self.lit[1][k], self.lit[2][k])
    }
}

/// `light`'s terms for the hits of `h` under the lecture's conventions: each lane's,
/// bit for bit, what [`light_term_as`] gives it, in vectors of four AVX2 lanes where
/// the processor has them, else of four SSE2 lanes.
#[inline(always)]
pub(super) fn light8(h: &Hits8, light: &Light) -> Lit8 {
    #[cfg(target_arch = "x86_64")]
    if let Some(avx2) = crate::geometry::bounds::x86::Avx2::detect() {
        // Always inlined into `run`'s function, so compiled for AVX2 with it (left a
        // call, every step became one: 30 % more instructions in `classic`'s render).
        return avx2.run(
            #[inline(always)]
            || light8_in(Eight(avx2), h, light),
        );
    }
    light8_in(Eight(Portable), h, light)
}

/// [`light8`] in the lanes of `a`.
#[inline(always)]
fn light8_in<L: Lanes4>(a: Eight<L>, h: &Hits8, light: &Light) -> Lit8 {
    let n = a.load3(&h.n);
    let (origin, to_light, t_max, colour, cone) = toward(a, light, a.load3(&h.p), n);
    let inside = match cone {
        Some((axis, cos_angle)) => a.ge(axis, a.splat(cos_angle)) & h.live,
        None => h.live,
    };
    let f = facing(a, to_light, n, a.load3(&h.v));
    let diffuse = a.scale(a.mul3(a.splat3(colour), a.load3(&h.diffuse)), f.lambert);
    // `pow` lane by lane, where the lone term calls it.
    let r_dot_v = a.store(f.r_dot_v);
    let (zero, has) = (a.splat(0.0), a.load(&h.has_specular));
    let mut power = [0.0; 8];
    for k in lanes_of(a.ne(has, zero) & inside) {
        power[k] = highlight(r_dot_v[k], h.shininess[k]);
    }
    let specular = a.scale(
        a.mul3(a.splat3(colour), a.load3(&h.specular)),
        a.load(&power),
    );
    // A black specular adds the lone term's `+0`: `colour ⊙ m.specular · 0` may be −0,
    // or NaN where a colour is beyond the numbers.
    let specular = [
        a.pick_gt(has, zero, specular[0], zero),
        a.pick_gt(has, zero, specular[1], zero),
        a.pick_gt(has, zero, specular[2], zero),
    ];
    let lit = a.add3(diffuse, specular);
    let cast = (a.ne(lit[0], zero) | a.ne(lit[1], zero) | a.ne(lit[2], zero)) & inside;
    let store3 = |v: [[L::V; 2]; 3]| [a.store(v[0]), a.store(v[1]), a.store(v[2])];
    Lit8 {
        cast,
        shadow: Rays8 {
            origin: store3(origin),
            dir: store3(to_light),
        },
        t_max: [t_max; 8],
        lit: store3(lit),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The offset is `1e-9 · max(1, |p|∞)`: the largest coordinate's magnitude, or 1.
    #[test]
    fn the_surface_offset_scales_with_the_largest_coordinate() {
        assert_eq!(surface_offset(DVec3::new(-3.0, 2.0, 1.0)), 1e-9 * 3.0);
        assert_eq!(surface_offset(DVec3::new(0.5, -250.0, 7.0)), 1e-9 * 250.0);
        assert_eq!(surface_offset(DVec3::new(0.5, 0.25, -0.75)), 1e-9);
        assert_eq!(surface_offset(DVec3::ZERO), 1e-9);
        // A NaN coordinate is passed over where it is compared, as `f64::max` would.
        assert_eq!(surface_offset(DVec3::new(f64::NAN, 0.5, 0.5)), 1e-9);
    }

    /// Numbers of every kind a hit can hold: ordinary ones, zeros of either sign,
    /// magnitudes above 1 (where the offset grows) and at the ends of the range.
    fn number() -> impl Strategy<Value = f64> {
        prop_oneof![
            6 => -4.0f64..4.0,
            1 => Just(0.0),
            1 => Just(-0.0),
            1 => -1e6f64..1e6,
            1 => prop_oneof![Just(1e-300), Just(-1e300), Just(1.0)],
        ]
    }

    fn vector() -> BoxedStrategy<DVec3> {
        [number(), number(), number()]
            .prop_map(DVec3::from_array)
            .boxed()
    }

    /// A colour, black or not, sometimes with a black channel, a channel of −0 (which
    /// is not negative) or one beyond the numbers (no scene holds one: the lanes are
    /// the lone term's all the same).
    fn colour() -> impl Strategy<Value = DVec3> {
        prop_oneof![
            4 => [0.0f64..1.0, 0.0f64..1.0, 0.0f64..1.0].prop_map(DVec3::from_array),
            1 => Just(DVec3::ZERO),
            1 => (0.0f64..1.0).prop_map(|g| DVec3::new(0.0, g, -0.0)),
            1 => (0.0f64..1.0).prop_map(|g| DVec3::new(f64::INFINITY, g, 1e300)),
        ]
    }

    fn material() -> impl Strategy<Value = Material> {
        (
            colour(),
            colour(),
            prop_oneof![Just(0.0), Just(1.0), 0.0f64..300.0],
        )
            .prop_map(|(diffuse, specular, shininess)| Material {
                ambient: DVec3::ZERO,
                diffuse,
                specular,
                shininess,
                mirror: DVec3::ZERO,
                transmission: DVec3::ZERO,
                ior: 1.5,
            })
    }

    /// Lights of each kind.
    fn light() -> BoxedStrategy<Light> {
        let direction = || vector().prop_map(|d| d.normalize_or(DVec3::NEG_Y));
        prop_oneof![
            (vector(), colour()).prop_map(|(position, colour)| Light::Point { position, colour }),
            (direction(), colour())
                .prop_map(|(direction, colour)| Light::Directional { direction, colour }),
            (vector(), direction(), -1.0f64..1.0, colour()).prop_map(
                |(position, direction, cos_angle, colour)| Light::Spot {
                    position,
                    direction,
                    cos_angle,
                    colour,
                }
            ),
        ]
        .boxed()
    }

    type Lane = (Surface, DVec3, Material, DVec3);

    /// A hit: its surface record, its normal facing the ray, its material, the ray's
    /// direction.
    fn hit() -> BoxedStrategy<Lane> {
        (vector(), vector(), vector(), material())
            .prop_map(|(point, n, dir, m)| {
                let s = Surface {
                    lambda: 1.0,
                    object: 0,
                    point,
                    object_point: point,
                    normal: n.normalize_or(DVec3::Y),
                    front: true,
                    face: None,
                };
                let dir = if dir == DVec3::ZERO { DVec3::Z } else { dir };
                (s, super::super::facing_normal(&s, dir), m, dir)
            })
            .boxed()
    }

    fn bits(v: DVec3) -> [u64; 3] {
        v.to_array().map(f64::to_bits)
    }

    /// `light8_in` in the lanes of `a` against the lone term of each lane's hit.
    fn lanes_agree<L: Lanes4>(
        a: Eight<L>,
        hits: &[Option<Lane>; 8],
        lights: &[Light],
    ) -> Result<(), TestCaseError> {
        let mut h = Hits8::EMPTY;
        h.fill(|k| {
            hits[k]
                .as_ref()
                .map(|(s, n, m, dir)| (s.point, *n, m, *dir))
        });
        for light in lights {
            let got = light8_in(a, &h, light);
            for (k, hit) in hits.iter().enumerate() {
                let Some((s, n, m, dir)) = hit else {
                    prop_assert_eq!(got.cast >> k & 1, 0, "lane {} has no hit", k);
                    continue;
                };
                let want = light_term_as::<Lecture>(light, s.point, *n, *dir, m);
                let cast = got.cast >> k & 1 == 1;
                prop_assert_eq!(cast, want.casts_shadow_ray(), "lane {}: {:?}", k, want);
                if cast {
                    let ray = &got.shadow.ray(k);
                    prop_assert_eq!(bits(ray.origin), bits(want.shadow_ray.origin));
                    prop_assert_eq!(bits(ray.dir), bits(want.shadow_ray.dir));
                    prop_assert_eq!(got.t_max[k].to_bits(), want.shadow_t_max.to_bits());
                    prop_assert_eq!(bits(got.lit(k)), bits(want.lit()), "lane {}", k);
                }
            }
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// Each lane of a packet's light terms is the lone term of its hit, bit for
        /// bit, in SSE2 lanes and, where the processor has them, in AVX2 lanes:
        /// whether it casts a shadow ray, the ray, its limit and what it adds. Some
        /// lanes have no hit, and a point light may sit on a hit point itself (where
        /// `l` is 0/0).
        #[test]
        fn a_packet_s_light_terms_are_each_hit_s_own(
            mut hits in prop::array::uniform8(prop::option::weighted(0.8, hit())),
            spare in hit(),
            mut lights in prop::collection::vec(light(), 1..4),
            on_a_point in any::<bool>(),
        ) {
            if hits.iter().all(Option::is_none) {
                hits[3] = Some(spare);
            }
            if on_a_point {
                let at = hits.iter().flatten().next().map_or(DVec3::ZERO, |h| h.0.point);
                lights.push(Light::Point { position: at, colour: DVec3::ONE });
            }
            lanes_agree(Eight(Portable), &hits, &lights)?;
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = crate::geometry::bounds::x86::Avx2::detect() {
                avx2.run(|| lanes_agree(Eight(avx2), &hits, &lights))?;
            }
        }
    }

    /// A light's specular term where `r·v < 0` is +0 for a shininess above 0 and the
    /// whole `L.colour ⊙ m.specular` for a shininess of 0 (`0⁰ = 1`); where `r·v > 0`
    /// it is `(r·v)^shininess`.
    #[test]
    fn the_specular_term_is_the_power_of_max_0_r_dot_v() {
        let s = Surface {
            lambda: 1.0,
            object: 0,
            point: DVec3::ZERO,
            object_point: DVec3::ZERO,
            normal: DVec3::Y,
            front: true,
            face: None,
        };
        let colour = DVec3::new(0.8, 0.6, 0.4);
        let light = Light::Point {
            position: DVec3::new(1.0, 1.0, 0.0),
            colour,
        };
        let material = |shininess| Material {
            ambient: DVec3::ZERO,
            diffuse: DVec3::splat(0.5),
            specular: DVec3::new(0.9, 0.5, 0.25),
            shininess,
            mirror: DVec3::ZERO,
            transmission: DVec3::ZERO,
            ior: 1.5,
        };
        // The light's mirror image about the normal points to −x: a view from +x sees
        // no highlight, one from −x does.
        let away = DVec3::new(-1.0, -0.2, 0.0);
        let toward = DVec3::new(1.0, -0.2, 0.0);
        for shininess in [0.0, 0.5, 1.0, 32.0, 200.0] {
            let m = material(shininess);
            let t = light_term_as::<Lecture>(&light, s.point, s.normal, away, &m);
            assert!(t.r_dot_v < 0.0);
            let want = if shininess == 0.0 {
                colour * m.specular
            } else {
                DVec3::ZERO
            };
            assert_eq!(
                t.specular.to_array().map(f64::to_bits),
                want.to_array().map(f64::to_bits),
                "shininess {shininess}"
            );
            let t = light_term_as::<Lecture>(&light, s.point, s.normal, toward, &m);
            assert!(t.r_dot_v > 0.0);
            assert_eq!(t.specular, colour * m.specular * t.r_dot_v.powf(shininess));
            assert!(t.specular.min_element() > 0.0);
        }
    }
}
