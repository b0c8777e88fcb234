//! The canonical shapes of `docs/spec/shapes.md`, each in its own object space, one file each.
//!
//! Every test takes a ray already carried into object space and returns the smallest
//! `λ` in `(t_min, t_max)` with the *part* that was hit (a cube face, a cap, a
//! triangle). Normals and other details are computed afterwards, for the closest hit
//! only. Each test reports its intermediate values to a [`Probe`].
//!
//! Each file implements [`CanonicalShape`] once. [`Shape`] is the closed enum the scene
//! holds and the world traces: every method is one `match` that forwards to the
//! implementation (pbrt's tagged dispatch, no `dyn`), so the tracer's `()` probe still
//! compiles away. [`ShapeName`], the name a document writes, comes from the same list:
//! the `shapes!` invocation below is the only place that enumerates the shapes.
//!
//! # Adding a shape
//!
//! 1. Write `shapes/<name>.rs` with its tests: a type implementing [`CanonicalShape`]
//!    (a unit struct when the name alone makes the shape), and declare it with
//!    `pub mod <name>;` here.
//! 2. Add one line to the `shapes!` list below: under `plain` for a unit struct, under
//!    `with_data` for a shape the document gives data for (a mesh; such a shape also
//!    needs its fields in `scene::document::ObjectDoc` and a branch in
//!    `scene::validate`, which the compiler then asks for).
//! 3. Add its name to `objects[].shape` in `api/scene.schema.json` (a test below checks
//!    that the schema lists exactly the shapes of this module).
//!
//! Scene documents, the world, hit data and explanations then know the shape.

pub mod cone;
pub mod cube;
pub mod cylinder;
pub mod disk;
pub mod mesh;
pub mod plane;
pub mod sphere;

use std::borrow::Cow;
use std::sync::Arc;

use glam::DVec3;

pub use mesh::Mesh;

use super::{
    arith::{Arith, Eight, Lanes4, One},
    bounds::{Aabb, lanes_of, lanes_where, per_lane},
    hit::{Face, Probe},
    ray::Ray,
    transform::Transform,
};

/// What a canonical shape is and does, in its own object space; each shape's file
/// implements it once. The world carries rays into object space and normals out.
///
/// Parts number what a ray can hit, from 0 (a cube face, a cap, a triangle): the
/// intersection reports one, and the normal, the face and the label read it back.
pub trait CanonicalShape {
    /// The name scene documents use for it: `"sphere"`.
    const NAME: &'static str;
    /// Whether it encloses a volume. Closed shapes report the outward normal; open ones
    /// the side facing the ray.
    const CLOSED: bool;
    /// Whether its quadratic surface is cut to `−1 ≤ y ≤ 1` (a cylinder's or a cone's
    /// side), so that a root outside that range does not count.
    const BOUNDED_QUADRIC: bool = false;
    /// Whether its side's equation can degenerate to a linear one, solved without
    /// reporting a quadratic (a cone, for rays parallel to a generator line).
    const LINEAR_SIDE: bool = false;
    /// The labels of its parts, by part index (an unknown index reads as the first);
    /// empty for a shape of one part, which is labelled by its name.
    const PARTS: &'static [&'static str] = &[];

    /// The object-space bounds; `None` for an unbounded shape, which every ray tests.
    fn bounds(&self) -> Option<Aabb>;

    /// The world-space bounds under `world_from_object`: by default the bounds of the
    /// transformed object box; a shape may give tighter ones.
    #[inline]
    fn world_bounds(&self, world_from_object: &Transform) -> Option<Aabb> {
        self.bounds()
            .map(|b| b.transformed(&world_from_object.forward))
    }

    /// Work done once before tracing (a mesh builds its BVH), so that rays find it done.
    #[inline]
    fn prepare(&self) {}

    /// The smallest `λ` in `(t_min, t_max)` of a ray in object space, with the part hit;
    /// every intermediate value goes to `probe`.
    fn intersect<P: Probe>(
        &self,
        ray: &Ray,
        t_min: f64,
        t_max: f64,
        probe: &mut P,
    ) -> Option<(f64, u32)>;

    /// [`CanonicalShape::intersect`] for the rays of the bit set `active` (a packet,
    /// in object space), each within `(t_min, t_max[lane])`, nothing recorded: by
    /// default one ray at a time; a shape with its own hierarchy (a mesh) traverses
    /// it once for all of them, with the same answers. `shared` says that the caller
    /// knows all eight rays to start at one origin (a camera's), so that a packet
    /// need not compare them to find out.
    #[inline]
    fn intersect8(
        &self,
        rays: &[Ray; 8],
        shared: bool,
        active: u32,
        t_min: f64,
        t_max: [f64; 8],
    ) -> [Option<(f64, u32)>; 8] {
        let _ = shared;
        per_lane(active, |lane| {
            self.intersect(&rays[lane], t_min, t_max[lane], &mut ())
        })
    }

    /// Whether anything is hit in `(t_min, t_max)` (shadow rays): by default the
    /// intersection with nothing recorded.
    #[inline]
    fn occludes(&self, ray: &Ray, t_min: f64, t_max: f64) -> bool {
        self.intersect(ray, t_min, t_max, &mut ()).is_some()
    }

    /// [`CanonicalShape::occludes`] for the rays of the bit set `active` (a packet of
    /// shadow rays, in object space), each within `(t_min, t_max[lane])`: the bit set
    /// of those occluded. By default one ray at a time; a mesh traverses its hierarchy
    /// once for all of them, with the same answers.
    #[inline]
    fn occludes8(&self, rays: &[Ray; 8], active: u32, t_min: f64, t_max: [f64; 8]) -> u32 {
        lanes_where(active, |lane| {
            self.occludes(&rays[lane], t_min, t_max[lane])
        })
    }

    /// The object-space normal, not normalised, at a point of a part: outward for a
    /// closed shape, the geometric normal for an open one.
    fn normal(&self, object_point: DVec3, part: u32) -> DVec3;

    /// [`CanonicalShape::normal`] of a part that is flat (a face, a cap, a plane),
    /// the same at every point of it; `None` for a curved part. A world finds each
    /// flat part's world normal once (`World::new`), not at every hit.
    #[inline]
    fn flat_normal(&self, _part: u32) -> Option<DVec3> {
        None
    }

    /// The cube face of a part, for shapes whose parts are faces.
    #[inline]
    fn face(&self, _part: u32) -> Option<Face> {
        None
    }

    /// The name of a part in explanations: a cube face's label, `"side"`, `"top"`,
    /// `"triangle 3"`; the shape's name for a shape of one part.
    fn part_label(&self, part: u32) -> Cow<'static, str> {
        let label = Self::PARTS.get(part as usize).or(Self::PARTS.first());
        Cow::Borrowed(label.copied().unwrap_or(Self::NAME))
    }
}

/// Declares the shapes once: [`Shape`], [`ShapeName`], [`NeedsData`] and the one
/// `match` per method that forwards to each shape's [`CanonicalShape`].
macro_rules! shapes {
    (
        plain { $( $(#[$pdoc:meta])* $P:ident: $PT:path, )* }
        with_data { $( $(#[$ddoc:meta])* $D:ident: $DT:path, )* }
    ) => {
        /// A shape as the scene describes it, ready to trace.
        #[derive(Debug, Clone, PartialEq)]
        pub enum Shape {
            $( $(#[$pdoc])* $P, )*
            $( $(#[$ddoc])* $D(Arc<$DT>), )*
        }

        /// A shape's name, as a scene document writes it (`"sphere"`).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum ShapeName {
            $( $(#[$pdoc])* $P, )*
            $( $(#[$ddoc])* $D, )*
        }

        /// A shape that its name alone does not make: the document gives its data.
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        pub enum NeedsData {
            $( $(#[$ddoc])* $D, )*
        }

        impl ShapeName {
            /// Every shape, in the order of the list.
            pub const ALL: &'static [ShapeName] = &[
                $( ShapeName::$P, )*
                $( ShapeName::$D, )*
            ];

            /// Their names, in the same order.
            pub const NAMES: &'static [&'static str] = &[
                $( <$PT as CanonicalShape>::NAME, )*
                $( <$DT as CanonicalShape>::NAME, )*
            ];
        }

        impl Shape {
            /// The shape of a name, or which data the document must give for it.
            pub fn plain(name: ShapeName) -> Result<Shape, NeedsData> {
                match name {
                    $( ShapeName::$P => Ok(Shape::$P), )*
                    $( ShapeName::$D => Err(NeedsData::$D), )*
                }
            }

            /// Which shape this is.
            #[inline]
            pub fn kind(&self) -> ShapeName {
                match self {
                    $( Shape::$P => ShapeName::$P, )*
                    $( Shape::$D(_) => ShapeName::$D, )*
                }
            }

            /// See [`CanonicalShape::CLOSED`].
            #[inline]
            pub fn is_closed(&self) -> bool {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::CLOSED, )*
                    $( Shape::$D(_) => <$DT as CanonicalShape>::CLOSED, )*
                }
            }

            /// See [`CanonicalShape::BOUNDED_QUADRIC`].
            pub fn bounded_quadric(&self) -> bool {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::BOUNDED_QUADRIC, )*
                    $( Shape::$D(_) => <$DT as CanonicalShape>::BOUNDED_QUADRIC, )*
                }
            }

            /// See [`CanonicalShape::LINEAR_SIDE`].
            pub fn linear_side(&self) -> bool {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::LINEAR_SIDE, )*
                    $( Shape::$D(_) => <$DT as CanonicalShape>::LINEAR_SIDE, )*
                }
            }

            /// See [`CanonicalShape::bounds`].
            pub fn bounds(&self) -> Option<Aabb> {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::bounds(&$PT), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::bounds(s), )*
                }
            }

            /// See [`CanonicalShape::world_bounds`].
            pub fn world_bounds(&self, world_from_object: &Transform) -> Option<Aabb> {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::world_bounds(&$PT, world_from_object), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::world_bounds(s, world_from_object), )*
                }
            }

            /// See [`CanonicalShape::prepare`].
            pub fn prepare(&self) {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::prepare(&$PT), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::prepare(s), )*
                }
            }

            /// See [`CanonicalShape::intersect`].
            #[inline(always)]
            pub fn intersect<P: Probe>(
                &self,
                ray: &Ray,
                t_min: f64,
                t_max: f64,
                probe: &mut P,
            ) -> Option<(f64, u32)> {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::intersect(&$PT, ray, t_min, t_max, probe), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::intersect(s, ray, t_min, t_max, probe), )*
                }
            }

            /// See [`CanonicalShape::intersect8`].
            #[inline(always)]
            pub fn intersect8(
                &self,
                rays: &[Ray; 8],
                shared: bool,
                active: u32,
                t_min: f64,
                t_max: [f64; 8],
            ) -> [Option<(f64, u32)>; 8] {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::intersect8(&$PT, rays, shared, active, t_min, t_max), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::intersect8(s, rays, shared, active, t_min, t_max), )*
                }
            }

            /// See [`CanonicalShape::occludes`].
            #[inline(always)]
            pub fn occludes(&self, ray: &Ray, t_min: f64, t_max: f64) -> bool {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::occludes(&$PT, ray, t_min, t_max), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::occludes(s, ray, t_min, t_max), )*
                }
            }

            /// See [`CanonicalShape::occludes8`].
            #[inline(always)]
            pub fn occludes8(&self, rays: &[Ray; 8], active: u32, t_min: f64, t_max: [f64; 8]) -> u32 {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::occludes8(&$PT, rays, active, t_min, t_max), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::occludes8(s, rays, active, t_min, t_max), )*
                }
            }

            /// See [`CanonicalShape::normal`].
            // Always inlined: where the compiler called it (from `World::put_surface`),
            // its normal came back through memory, and the caller's wider loads of it
            // waited for its narrower stores; `classic`'s hit data traced 46 % slower.
            #[inline(always)]
            pub fn normal(&self, object_point: DVec3, part: u32) -> DVec3 {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::normal(&$PT, object_point, part), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::normal(s, object_point, part), )*
                }
            }

            /// See [`CanonicalShape::flat_normal`].
            pub fn flat_normal(&self, part: u32) -> Option<DVec3> {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::flat_normal(&$PT, part), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::flat_normal(s, part), )*
                }
            }

            /// See [`CanonicalShape::face`].
            #[inline]
            pub fn face(&self, part: u32) -> Option<Face> {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::face(&$PT, part), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::face(s, part), )*
                }
            }

            /// See [`CanonicalShape::part_label`].
            pub fn part_label(&self, part: u32) -> Cow<'static, str> {
                match self {
                    $( Shape::$P => <$PT as CanonicalShape>::part_label(&$PT, part), )*
                    $( Shape::$D(s) => <$DT as CanonicalShape>::part_label(s, part), )*
                }
            }
        }
    };
}

shapes! {
    plain {
        /// The unit sphere `p · p = 1`.
        Sphere: sphere::Sphere,
        /// The cube `[-1, 1]³`.
        Cube: cube::Cube,
        /// The plane `y = 0`.
        Plane: plane::Plane,
        /// The disk `y = 0, x² + z² ≤ 1`.
        Disk: disk::Disk,
        /// The capped cylinder `x² + z² = 1, −1 ≤ y ≤ 1`.
        Cylinder: cylinder::Cylinder,
        /// The capped cone with apex `(0, 1, 0)` and base radius 1 at `y = −1`.
        Cone: cone::Cone,
    }
    with_data {
        /// Triangles in object space.
        Mesh: mesh::Mesh,
    }
}

impl Shape {
    /// The name used in scene documents.
    #[inline]
    pub fn name(&self) -> &'static str {
        self.kind().as_str()
    }

    /// [`Shape::intersect`] for eight rays at once, in lanes, nothing recorded, for the
    /// shapes that have such a test (sphere, cube, cylinder, cone, disk): the bit set
    /// of the lanes that hit in `(t_min, t_max[lane])`, and for those the `λ` and part
    /// each ray finds alone, bit for bit; `None` for the others. `rays` gives the eight
    /// rays in object space (origins, directions), each lane a ray, and is called only
    /// for a shape that has the test.
    #[allow(clippy::type_complexity)]
    #[inline(always)]
    pub(crate) fn intersect_in_lanes8<L: Lanes4>(
        &self,
        n: Eight<L>,
        rays: impl FnOnce() -> ([[L::V; 2]; 3], [[L::V; 2]; 3]),
        t_min: f64,
        t_max: &[f64; 8],
    ) -> Option<(u32, [f64; 8], [u32; 8])> {
        // Each test called by name, not chosen as a function pointer: it is then
        // inlined, in the lanes' instructions.
        macro_rules! in_lanes {
            ($test:path) => {{
                let (origin, dir) = rays();
                $test(n, origin, dir, t_min, t_max)
            }};
        }
        Some(match self {
            Shape::Sphere => {
                let (hit, lambda) = in_lanes!(sphere::intersect8);
                (hit, lambda, [0; 8])
            }
            Shape::Cube => in_lanes!(cube::intersect8),
            Shape::Cylinder => in_lanes!(cylinder::intersect8),
            Shape::Cone => in_lanes!(cone::intersect8),
            Shape::Disk => in_lanes!(disk::intersect8),
            Shape::Plane | Shape::Mesh(_) => return None,
        })
    }
}

impl ShapeName {
    /// The name as documents write it.
    #[inline]
    pub fn as_str(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// The shape a document's name means, if any.
    pub fn from_name(name: &str) -> Option<ShapeName> {
        Self::ALL.iter().copied().find(|n| n.as_str() == name)
    }
}

impl std::fmt::Display for ShapeName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// Whether the roots of `a λ² + b λ + c = 0` that [`solve_quadratic`] would give,
/// for `a ≥ 0`, are all at `λ ≤ 0`, as computed, because `c > 0` and `b > 0`: then no
/// `t_min ≥ 0` admits either, and the square root and divisions can be skipped. For
/// the sphere and the cylinder's side, `c > 0` is a ray starting outside the surface
/// and `b > 0` one moving away from its centre or axis, which every shadow and mirror
/// ray leaving that surface is, in its own object. (The cone's side qualifies only
/// where its `a > 0`, for rays flatter than its generator lines; shadow rays toward
/// lights overhead are mostly steeper, and it was left out: README, "Speed".)
///
/// Exact, not approximate: with `a ≥ 0` and `c > 0`, `4ac ≥ 0`, so the rounded
/// discriminant is at most `fl(b²)` and its rounded square root at most
/// `fl(√fl(b²)) = b` (square roots are correctly rounded, hence monotone, and give
/// back `|b|` from `fl(b²)` wherever `b²` is a normal number: hence `b > 10⁻¹⁵⁰`).
/// So `−b + √disc ≤ 0`, and both roots are `≤ 0`; a zero discriminant's root `−b/2a`
/// is negative, and `a = 0` gives no roots at all. Where `b²` or `4ac` overflows, the
/// roots are `+∞`, `−∞` or NaN, or there are none, and no interval admits any of them.
#[inline(always)]
fn leaves_from_outside(b: f64, c: f64) -> bool {
    c > 0.0 && b > 1e-150
}

/// [`solve_quadratic`]'s roots where some may lie beyond `t_min`; none where
/// [`leaves_from_outside`] shows them all at `λ ≤ 0` and `t_min ≥ 0` refuses them.
/// A probe recording the roots (a pixel's explanation) always gets the whole test.
#[inline(always)]
fn roots_ahead<P: super::hit::Probe>(
    surface: &'static str,
    a: f64,
    b: f64,
    c: f64,
    t_min: f64,
    probe: &mut P,
) -> [Option<f64>; 2] {
    if !probe.active() && t_min >= 0.0 && leaves_from_outside(b, c) {
        return [None, None];
    }
    solve_quadratic(surface, a, b, c, probe)
}

/// Solves `a λ² + b λ + c = 0` the way the lecture does, reporting to `probe`, and
/// returns the real roots in increasing order (`a > 0` assumed by callers that need order).
#[inline(always)]
pub(crate) fn solve_quadratic<P: super::hit::Probe>(
    surface: &'static str,
    a: f64,
    b: f64,
    c: f64,
    probe: &mut P,
) -> [Option<f64>; 2] {
    let disc = discriminant(One, a, b, c);
    let roots = if disc < 0.0 || a == 0.0 {
        [None, None]
    } else {
        let (r0, r1) = roots(One, a, b, disc);
        if disc == 0.0 {
            // `−b − √0` is `−b`, bit for bit: the one root `−b / 2a`.
            [Some(r0), None]
        } else {
            [Some(r0.min(r1)), Some(r0.max(r1))]
        }
    };
    if probe.active() {
        probe.quadratic(&super::hit::QuadraticTest {
            surface,
            a,
            b,
            c,
            discriminant: disc,
            roots,
        });
    }
    roots
}

/// The discriminant `b² − 4ac`, in one number or in lanes.
#[inline(always)]
pub(crate) fn discriminant<A: Arith>(n: A, a: A::N, b: A::N, c: A::N) -> A::N {
    n.sub(n.mul(b, b), n.mul(n.mul(n.splat(4.0), a), c))
}

/// The lanes where a side's point at `λ = t` lies within its height, `−1 ≤ y ≤ 1`
/// (`y = y₀ + tΔy`), in one number or in lanes: the cylinder's and the cone's side.
#[inline(always)]
pub(crate) fn on_side<A: Arith>(n: A, y0: A::N, dy: A::N, t: A::N) -> u32 {
    within_unit(n, n.add(y0, n.mul(t, dy)))
}

/// Offers `nearest` the roots of a side's quadratic `a λ² + b λ + c = 0` (a cylinder's,
/// a cone's) as part 0, in lanes: where it has real roots as [`solve_quadratic`] finds
/// them (`disc ≥ 0`, `a ≠ 0`) and each root's point lies within the side's height
/// ([`on_side`], from the rays' `y₀` and `Δy`). Both roots are offered: the nearer
/// valid one is kept whichever comes first, as the lone test's sorted loop keeps it.
#[inline(always)]
pub(crate) fn offer_side_roots8<L: Lanes4>(
    n: Eight<L>,
    nearest: &mut Nearest8<L>,
    a: [L::V; 2],
    b: [L::V; 2],
    c: [L::V; 2],
    y0: [L::V; 2],
    dy: [L::V; 2],
) {
    let disc = discriminant(n, a, b, c);
    let zero = n.splat(0.0);
    let real = n.ge(disc, zero) & n.ne(a, zero);
    if real != 0 {
        let (r0, r1) = roots(n, a, b, disc);
        for t in [r0, r1] {
            nearest.offer(n, real & on_side(n, y0, dy, t), t, 0);
        }
    }
}

/// The lanes where `−1 ≤ p ≤ 1` (not where `p` is NaN), in one number or in lanes:
/// within a canonical shape's extent along an axis.
#[inline(always)]
pub(crate) fn within_unit<A: Arith>(n: A, p: A::N) -> u32 {
    n.ge(p, n.splat(-1.0)) & n.ge(n.splat(1.0), p)
}

/// The nearest hit so far of eight rays in lanes (each lane a ray), as a shape's test
/// in lanes goes through its candidates in the lone test's order: a candidate is
/// taken where it lies in `(t_min, limit)`, the limit being the nearest hit so far (at
/// first `t_max`), so a nearer one replaces it and a tie stays with the earlier, as
/// the lone test's `t > t_min && t < limit`.
pub(crate) struct Nearest8<L: Lanes4> {
    hit: u32,
    first: [f64; 8],
    part: [u32; 8],
    low: [L::V; 2],
    limit: [L::V; 2],
}

impl<L: Lanes4> Nearest8<L> {
    /// None yet, each lane limited to `(t_min, t_max[lane])`.
    #[inline(always)]
    pub(crate) fn new(n: Eight<L>, t_min: f64, t_max: &[f64; 8]) -> Nearest8<L> {
        Nearest8 {
            hit: 0,
            first: *t_max,
            part: [0; 8],
            low: n.splat(t_min),
            limit: n.load(t_max),
        }
    }

    /// `t` as a hit of part `part` in the lanes of `valid` where it lies within the
    /// interval.
    #[inline(always)]
    pub(crate) fn offer(&mut self, n: Eight<L>, valid: u32, t: [L::V; 2], part: u32) {
        let take = valid & n.gt(t, self.low) & n.gt(self.limit, t) & 0xff;
        if take != 0 {
            let t = n.store(t);
            for lane in lanes_of(take) {
                (self.first[lane], self.part[lane]) = (t[lane], part);
            }
            self.hit |= take;
            self.limit = n.load(&self.first);
        }
    }

    /// The lanes with a hit, and for those its `λ` and part.
    #[inline(always)]
    pub(crate) fn found(self) -> (u32, [f64; 8], [u32; 8]) {
        (self.hit, self.first, self.part)
    }
}

/// The roots `(−b − √disc) / 2a` and `(−b + √disc) / 2a` for a discriminant `disc ≥ 0`,
/// in one number or in lanes: in that order the nearer and the farther where `a > 0`.
#[inline(always)]
pub(crate) fn roots<A: Arith>(n: A, a: A::N, b: A::N, disc: A::N) -> (A::N, A::N) {
    let (s, minus_b, two_a) = (n.sqrt(disc), n.neg(b), n.mul(n.splat(2.0), a));
    (
        n.div(n.sub(minus_b, s), two_a),
        n.div(n.add(minus_b, s), two_a),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::arith::Portable;
    #[cfg(target_arch = "x86_64")]
    use crate::geometry::bounds::x86::Avx2;
    use crate::geometry::hit::{FaceTest, Probe};
    use crate::geometry::ray::lanes3;
    use proptest::prelude::*;

    /// A probe that asks for every value, so that the tests it watches take no
    /// shortcut: with it, a shape's test is the lecture's whole formula.
    pub(super) struct Watching;

    impl Probe for Watching {
        fn active(&self) -> bool {
            true
        }
    }

    /// How far off a surface the property tests' rays start, as a fraction of its
    /// size: on it, a hair outside or inside, or a little either way.
    pub(super) fn off_surface() -> impl Strategy<Value = f64> {
        prop_oneof![Just(0.0), Just(1e-9), Just(-1e-9), -1e-6f64..1e-6]
    }

    /// A scale for a ray's direction: none, or one that takes its coefficients below
    /// the normal numbers or near overflow.
    pub(super) fn ray_scale() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(1.0),
            Just(1e-160),
            Just(1e-75),
            Just(1e150),
            Just(1e200)
        ]
    }

    /// A `t_min`: the shader's, zero, negative (which the shortcut must not take) or any.
    pub(super) fn any_t_min() -> impl Strategy<Value = f64> {
        prop_oneof![Just(1e-9), Just(0.0), Just(-1.0), 0.0f64..2.0]
    }

    /// A `t_max`: unbounded, or a segment's end.
    pub(super) fn any_t_max() -> impl Strategy<Value = f64> {
        prop_oneof![Just(f64::INFINITY), 0.0f64..8.0]
    }

    /// A coefficient of any sign and scale, zeros and the extremes included (most of
    /// them of the size rays of a scene give).
    fn coefficient() -> impl Strategy<Value = f64> {
        let extreme = prop_oneof![
            Just(1e-320),
            Just(1e-160),
            Just(1e-150),
            Just(1e150),
            Just(1e160),
            Just(1e300)
        ];
        prop_oneof![
            1 => Just(0.0),
            1 => Just(f64::MIN_POSITIVE),
            6 => -4.0f64..4.0,
            2 => (-4.0f64..4.0, extreme).prop_map(|(x, s)| x * s),
        ]
    }

    proptest! {
        /// `roots_ahead` drops only roots that an interval `(t_min, t_max)` with
        /// `t_min ≥ 0` refuses: the roots in `(t_min, ∞)` are `solve_quadratic`'s, bit
        /// for bit, for every `a ≥ 0`, `b` and `c`. (Where `b²` overflows, a root may be
        /// `+∞`, which no `t < t_max` admits.) Each is also taken as a ray's would be
        /// with its direction scaled by `s` (`a s²`, `b s`, `c`), where `b²` and `4ac`
        /// may fall below the normal numbers together.
        #[test]
        fn roots_ahead_drops_only_roots_behind(
            a in coefficient().prop_map(f64::abs),
            b in coefficient(),
            c in coefficient(),
            s in prop_oneof![Just(1e-160), Just(1e-158), Just(1e-80), Just(1e150)],
            t_min in prop_oneof![Just(0.0), Just(1e-9), 0.0f64..2.0],
        ) {
            let beyond = |roots: [Option<f64>; 2]| {
                roots.map(|r| r.filter(|&t| t > t_min && t < f64::INFINITY).map(f64::to_bits))
            };
            for (a, b, c) in [(a, b, c), (a * s * s, b * s, c)] {
                prop_assert_eq!(
                    beyond(roots_ahead("q", a, b, c, t_min, &mut ())),
                    beyond(solve_quadratic("q", a, b, c, &mut ())),
                    "a = {:e}, b = {:e}, c = {:e}", a, b, c
                );
            }
        }
    }

    #[test]
    fn roots_ahead_skips_only_rays_leaving_from_outside() {
        // Outside and moving away: both roots negative, none computed.
        assert_eq!(
            solve_quadratic("q", 1.0, 3.0, 2.0, &mut ()),
            [Some(-2.0), Some(-1.0)]
        );
        assert_eq!(roots_ahead("q", 1.0, 3.0, 2.0, 0.0, &mut ()), [None, None]);
        // Outside and moving closer, or inside: the roots as solved.
        assert_eq!(
            roots_ahead("q", 1.0, -3.0, 2.0, 0.0, &mut ()),
            [Some(1.0), Some(2.0)]
        );
        assert_eq!(
            roots_ahead("q", 1.0, 3.0, -4.0, 0.0, &mut ()),
            [Some(-4.0), Some(1.0)]
        );
        // A negative `t_min` would admit the roots behind, and a probe asks for them.
        assert_eq!(
            roots_ahead("q", 1.0, 3.0, 2.0, -1.5, &mut ()),
            [Some(-2.0), Some(-1.0)]
        );
        assert_eq!(
            roots_ahead("q", 1.0, 3.0, 2.0, 0.0, &mut Watching),
            [Some(-2.0), Some(-1.0)]
        );
    }

    /// A coordinate of a ray for the tests in lanes: on the half grid (a cube's faces,
    /// edges and corners, a cap's rim, the cone's apex and base), anywhere near the
    /// shapes, at the parallel threshold, or extreme.
    fn coordinate() -> impl Strategy<Value = f64> {
        prop_oneof![
            (-8i32..8).prop_map(|c| c as f64 * 0.5),
            -3.0f64..3.0,
            Just(0.0),
            Just(-0.0),
            Just(1e-13),
            Just(-1e-12),
            Just(1e-12),
            Just(1e-300),
            Just(-1e200),
            Just(f64::INFINITY),
        ]
    }

    /// A ray for the tests in lanes: its coordinates of [`coordinate`], or from such an
    /// origin along one of the cone's generator lines (where its side's quadratic is
    /// linear: `a = Δx² + Δz² − Δy²/4 = 0` exactly), scaled by a power of two.
    fn lane_ray() -> BoxedStrategy<Ray> {
        let origin = || prop::array::uniform3(coordinate()).prop_map(DVec3::from_array);
        let free = (origin(), prop::array::uniform3(coordinate()))
            .prop_map(|(o, d)| Ray::new(o, DVec3::from_array(d)));
        let generator = (
            origin(),
            prop::sample::select(vec![
                DVec3::new(0.5, 1.0, 0.0),
                DVec3::new(-0.5, -1.0, 0.0),
                DVec3::new(0.0, 1.0, -0.5),
                DVec3::new(0.0, -1.0, 0.5),
            ]),
            prop::sample::select(vec![1.0, 0.25, 8.0]),
        )
            .prop_map(|(o, d, scale)| Ray::new(o, d * scale));
        // Boxed: eight of the two unboxed kinds' value trees overflowed a test
        // thread's stack.
        prop_oneof![3 => free, 1 => generator].boxed()
    }

    /// `shape`'s test in lanes ([`Shape::intersect_in_lanes8`]) of `rays`, each to its
    /// own `t_max`, against its lone test ([`Shape::intersect`]) of each ray: each
    /// lane's hit, `λ` (bit for bit) and part, in SSE2 lanes and, where the processor
    /// has them, in AVX2 lanes. Fails for a shape without a test in lanes.
    pub(super) fn lanes_agree(
        shape: &Shape,
        rays: &[Ray; 8],
        t_min: f64,
        t_max: &[f64; 8],
    ) -> Result<(), TestCaseError> {
        agree_in(Eight(Portable), shape, rays, t_min, t_max)?;
        #[cfg(target_arch = "x86_64")]
        if let Some(avx2) = Avx2::detect() {
            avx2.run(|| agree_in(Eight(avx2), shape, rays, t_min, t_max))?;
        }
        Ok(())
    }

    /// [`lanes_agree`] in the lanes of `n`.
    fn agree_in<L: Lanes4>(
        n: Eight<L>,
        shape: &Shape,
        rays: &[Ray; 8],
        t_min: f64,
        t_max: &[f64; 8],
    ) -> Result<(), TestCaseError> {
        let lanes = |v: fn(&Ray) -> DVec3| n.load3(&lanes3(rays, v));
        let carried = || (lanes(|r| r.origin), lanes(|r| r.dir));
        let Some((hit, first, part)) = shape.intersect_in_lanes8(n, carried, t_min, t_max) else {
            return Err(TestCaseError::fail(format!(
                "{} has no test in lanes",
                shape.name()
            )));
        };
        for (k, r) in rays.iter().enumerate() {
            let alone = shape.intersect(r, t_min, t_max[k], &mut ());
            let lane = (hit >> k & 1 == 1).then_some((first[k], part[k]));
            prop_assert_eq!(
                lane.map(|(t, i)| (t.to_bits(), i)),
                alone.map(|(t, i)| (t.to_bits(), i)),
                "{} lane {} {:?}",
                shape.name(),
                k,
                r
            );
        }
        Ok(())
    }

    /// The shapes with a test in lanes: those a packet tests in lanes.
    fn shapes_in_lanes() -> Vec<Shape> {
        every_shape()
            .into_iter()
            .filter(|s| {
                let n = Eight(Portable);
                let rays = || (n.splat3(DVec3::ZERO), n.splat3(DVec3::Y));
                s.intersect_in_lanes8(n, rays, 0.0, &[1.0; 8]).is_some()
            })
            .collect()
    }

    /// Every shape but the plane (which a packet tests from its rays' heights alone)
    /// and the mesh (which has its own packet test) is tested in lanes; a shape that
    /// lost its test would leave the property test below without it.
    #[test]
    fn the_shapes_a_packet_tests_in_lanes() {
        let names: Vec<_> = shapes_in_lanes().iter().map(Shape::name).collect();
        assert_eq!(names, ["sphere", "cube", "disk", "cylinder", "cone"]);
    }

    proptest! {
        /// Eight rays at once, each in its lane to its own `t_max`, against every shape
        /// with a test in lanes: through a cube's faces, edges and corners, a cap's rim,
        /// the cone's apex, along its generator lines, parallel to faces and caps by the
        /// threshold, from inside, with coordinates of every scale. Each lane finds the
        /// part and `λ` its ray finds alone, bit for bit.
        #[test]
        fn shapes_in_lanes_find_what_each_ray_finds_alone(
            rays in prop::array::uniform8(lane_ray()),
            t_min in prop_oneof![Just(1e-9), Just(0.0), Just(-1.0)],
            t_max in prop::array::uniform8(prop_oneof![
                Just(f64::INFINITY),
                Just(1.5),
                Just(0.5),
                0.0f64..6.0,
            ]),
        ) {
            for shape in shapes_in_lanes() {
                lanes_agree(&shape, &rays, t_min, &t_max)?;
            }
        }
    }

    fn every_shape() -> Vec<Shape> {
        ShapeName::ALL
            .iter()
            .map(|&n| match Shape::plain(n) {
                Ok(s) => s,
                // A tetrahedron around the origin, inside the canonical box.
                Err(NeedsData::Mesh) => Shape::Mesh(Arc::new(Mesh::new(
                    vec![
                        DVec3::new(0.9, 0.9, 0.9),
                        DVec3::new(0.9, -0.9, -0.9),
                        DVec3::new(-0.9, 0.9, -0.9),
                        DVec3::new(-0.9, -0.9, 0.9),
                    ],
                    vec![[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]],
                ))),
            })
            .collect()
    }

    #[test]
    fn the_schema_lists_exactly_these_shapes() {
        let schema: serde_json::Value = serde_json::from_str(include_str!(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/api/scene.schema.json"
        )))
        .unwrap();
        let listed = &schema["$defs"]["object"]["properties"]["shape"]["enum"];
        assert_eq!(listed, &serde_json::json!(ShapeName::NAMES));
    }

    #[test]
    fn names_and_shapes_correspond() {
        assert_eq!(ShapeName::ALL.len(), ShapeName::NAMES.len());
        for (s, &n) in every_shape().iter().zip(ShapeName::ALL) {
            assert_eq!(s.kind(), n);
            assert_eq!(s.name(), n.as_str());
            assert_eq!(ShapeName::from_name(n.as_str()), Some(n));
            assert_eq!(n.to_string(), n.as_str());
        }
        assert_eq!(ShapeName::from_name("teapot"), None);
        assert_eq!(
            Shape::plain(ShapeName::Mesh),
            Err(NeedsData::Mesh),
            "a mesh needs its triangles"
        );
    }

    /// Keeps the planar face tests, to compare with the part reported.
    #[derive(Default)]
    struct Faces(Vec<FaceTest>);

    impl Probe for Faces {
        fn face(&mut self, f: &FaceTest) {
            self.0.push(*f);
        }
        fn active(&self) -> bool {
            true
        }
    }

    /// Rays from a sphere of radius 4 toward points of `[-1.5, 1.5]³`, the same each run.
    fn rays(n: usize) -> impl Iterator<Item = Ray> {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        (0..n).map(move |_| {
            let from = DVec3::new(next(), next(), next()).normalize_or(DVec3::Z) * 4.0;
            let to = DVec3::new(next(), next(), next()) * 1.5;
            Ray::new(from, to - from)
        })
    }

    #[test]
    fn hits_lie_within_the_bounds_and_agree_with_occlusion_and_labels() {
        for shape in every_shape() {
            let mut hits = 0;
            for ray in rays(4000) {
                let mut faces = Faces::default();
                let hit = shape.intersect(&ray, 1e-9, f64::INFINITY, &mut faces);
                assert_eq!(
                    shape.occludes(&ray, 1e-9, f64::INFINITY),
                    hit.is_some(),
                    "{} {ray:?}",
                    shape.name()
                );
                let Some((t, part)) = hit else { continue };
                hits += 1;
                let p = ray.at(t);
                if let Some(b) = shape.bounds() {
                    let slack = DVec3::splat(1e-9);
                    assert!(
                        p.cmpge(b.min - slack).all() && p.cmple(b.max + slack).all(),
                        "{} hit at {p} outside {b:?}",
                        shape.name()
                    );
                }
                let n = shape.normal(p, part);
                assert!(n.is_finite() && n != DVec3::ZERO, "{}", shape.name());
                // A planar part's label is the label its face test reported under.
                let label = shape.part_label(part);
                if let Some(f) = faces.0.iter().find(|f| f.within && f.lambda == Some(t)) {
                    assert_eq!(f.face, label, "{}", shape.name());
                }
            }
            assert!(hits > 100, "{}: only {hits} hits", shape.name());
        }
    }

    #[test]
    fn parts_have_their_labels() {
        let label = |s: &Shape, part: u32| s.part_label(part).into_owned();
        assert_eq!(label(&Shape::Sphere, 0), "sphere");
        assert_eq!(label(&Shape::Plane, 0), "plane");
        assert_eq!(label(&Shape::Cube, 5), "-z");
        assert_eq!(label(&Shape::Cylinder, 2), "bottom");
        assert_eq!(label(&Shape::Cone, 1), "base");
        assert_eq!(label(&Shape::Cone, 7), "side");
        let mesh = every_shape().pop().unwrap();
        assert_eq!(label(&mesh, 3), "triangle 3");
        assert_eq!(Shape::Cube.face(1), Some(Face::NegX));
        assert_eq!(Shape::Cylinder.face(1), None);
        assert!(Shape::Cone.bounded_quadric() && Shape::Cone.linear_side());
        assert!(Shape::Cylinder.bounded_quadric() && !Shape::Cylinder.linear_side());
        assert!(!Shape::Sphere.bounded_quadric());
        assert!(!Shape::Plane.is_closed() && !mesh.is_closed() && Shape::Cube.is_closed());
    }
}
