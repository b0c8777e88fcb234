//! Axis-aligned bounding boxes and the ray-box slab test used by the BVH.

use glam::{DAffine3, DVec3};

use super::arith::{Arith, Eight, Lanes4, One};
use super::ray::{Ray, Rays8};
use wide::{f32x4, f32x8, f64x2};

// The one module with `unsafe`: calling code compiled for AVX2 or AVX-512, once the
// processor is known to have it.
#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
pub mod x86;

/// An axis-aligned box; empty when `min > max` on any axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    /// The low corner.
    pub min: DVec3,
    /// The high corner.
    pub max: DVec3,
}

impl Aabb {
    /// The empty box, identity of `union`.
    pub const EMPTY: Aabb = Aabb {
        min: DVec3::splat(f64::INFINITY),
        max: DVec3::splat(f64::NEG_INFINITY),
    };

    /// The box `[-1, 1]³`, which holds every bounded canonical shape.
    pub const CANONICAL: Aabb = Aabb {
        min: DVec3::splat(-1.0),
        max: DVec3::splat(1.0),
    };

    /// The smallest box holding both.
    pub fn union(&self, o: &Aabb) -> Aabb {
        Aabb {
            min: self.min.min(o.min),
            max: self.max.max(o.max),
        }
    }

    /// The smallest box holding `self` and `p`.
    pub fn grow(&self, p: DVec3) -> Aabb {
        Aabb {
            min: self.min.min(p),
            max: self.max.max(p),
        }
    }

    /// The centre.
    pub fn centroid(&self) -> DVec3 {
        0.5 * (self.min + self.max)
    }

    /// Half the surface area (the SAH's cost measure; the factor 2 cancels).
    pub fn half_area(&self) -> f64 {
        let e = (self.max - self.min).max(DVec3::ZERO);
        e.x * e.y + e.y * e.z + e.z * e.x
    }

    /// Whether the box holds nothing.
    pub fn is_empty(&self) -> bool {
        self.min.cmpgt(self.max).any()
    }

    /// The box of the eight corners of `self` carried by `m`.
    pub fn transformed(&self, m: &DAffine3) -> Aabb {
        let mut out = Aabb::EMPTY;
        for i in 0..8 {
            let c = DVec3::new(
                if i & 1 == 0 { self.min.x } else { self.max.x },
                if i & 2 == 0 { self.min.y } else { self.max.y },
                if i & 4 == 0 { self.min.z } else { self.max.z },
            );
            out = out.grow(m.transform_point3(c));
        }
        out
    }

    /// The box grown by a tiny relative margin, so that rounding in the slab test never
    /// rejects a ray that the exact shape test would accept.
    pub fn padded(&self) -> Aabb {
        let pad = (self.max - self.min)
            .abs()
            .max(self.min.abs().max(self.max.abs()))
            * 1e-9
            + 1e-300;
        Aabb {
            min: self.min - pad,
            max: self.max + pad,
        }
    }
}

/// `d`, or where it is below 10⁻³⁰⁰ in magnitude (a zero, a subnormal) 10⁻³⁰⁰ of its
/// sign, so that its reciprocal is finite and `0 · ∞ = NaN` never arises. A ray
/// running exactly in a box's face plane then counts as leaving it; the BVH pads its
/// boxes (see [`Aabb::padded`]), so such a plane never holds a surface point.
#[inline(always)]
fn nonzero(d: f64) -> f64 {
    if d.abs() < 1e-300 {
        1e-300f64.copysign(d)
    } else {
        d
    }
}

/// [`SlabRay::enter`] in numbers `A` (one ray, or eight in lanes): the entry `λ` of
/// rays from `origin` (reciprocal directions `inv`) into the box `(min, max)` clipped
/// to `[t_min, t_max]`, and the rays that enter (as a bit set).
#[inline(always)]
fn slab_enter<A: Arith>(
    a: A,
    origin: [A::N; 3],
    inv: [A::N; 3],
    (min, max): (DVec3, DVec3),
    t_min: A::N,
    t_max: A::N,
) -> (A::N, u32) {
    let (lo, hi) = (min.to_array(), max.to_array());
    // Written out, not by closures: those were left calls (attributes that would
    // inline them are not allowed on closures bound to names).
    let t0x = a.mul(a.sub(a.splat(lo[0]), origin[0]), inv[0]);
    let t1x = a.mul(a.sub(a.splat(hi[0]), origin[0]), inv[0]);
    let t0y = a.mul(a.sub(a.splat(lo[1]), origin[1]), inv[1]);
    let t1y = a.mul(a.sub(a.splat(hi[1]), origin[1]), inv[1]);
    let t0z = a.mul(a.sub(a.splat(lo[2]), origin[2]), inv[2]);
    let t1z = a.mul(a.sub(a.splat(hi[2]), origin[2]), inv[2]);
    let near = slab_max(
        a,
        slab_max(a, slab_min(a, t0x, t1x), slab_min(a, t0y, t1y)),
        slab_max(a, slab_min(a, t0z, t1z), t_min),
    );
    let far = slab_min(
        a,
        slab_min(a, slab_max(a, t0x, t1x), slab_max(a, t0y, t1y)),
        slab_min(a, slab_max(a, t0z, t1z), t_max),
    );
    // 1 + 2γ₃ (pbrt): the far distance is rounded up so grazing rays are not lost.
    let far = a.mul(far, a.splat(1.0 + 4.0 * f64::EPSILON));
    (near, a.ge(far, near))
}

/// Eight rays prepared for the slab test together: [`SlabRay::new`]'s reciprocals of
/// their directions made in lanes, and their entry into a box tested in lanes
/// ([`SlabRays8::enter8`]), each ray then traversing alone ([`SlabRays8::lane`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct SlabRays8 {
    /// `inv[a][k]`: coordinate `a` of ray `k`'s reciprocal direction.
    inv: [[f64; 8]; 3],
}

impl SlabRays8 {
    /// `rays` prepared in lanes `n`: each ray's numbers, bit for bit, those
    /// [`SlabRay::new`] makes of it.
    #[inline(always)]
    pub(crate) fn new<L: Lanes4>(n: Eight<L>, rays: &Rays8) -> SlabRays8 {
        let (one, tiny) = (n.splat(1.0), n.splat(1e-300));
        let inv = std::array::from_fn(|a| {
            let d = n.load(&rays.dir[a]);
            let mut inv = n.store(n.div(one, d));
            // A magnitude below 10⁻³⁰⁰ (rare) is replaced lane by lane (`nonzero`).
            for k in lanes_of(n.gt(tiny, n.abs(d))) {
                inv[k] = 1.0 / nonzero(rays.dir[a][k]);
            }
            inv
        });
        SlabRays8 { inv }
    }

    /// The rays of `rays` (these rays' origins) that enter the box `(min, max)` within
    /// `[t_min, t_max[k]]`, as a bit set: [`SlabRay::enter`] of each, in lanes `n`.
    #[inline(always)]
    pub(crate) fn enter8<L: Lanes4>(
        &self,
        n: Eight<L>,
        rays: &Rays8,
        bounds: (DVec3, DVec3),
        t_min: f64,
        t_max: &[f64; 8],
    ) -> u32 {
        let (origin, inv) = (n.load3(&rays.origin), n.load3(&self.inv));
        slab_enter(n, origin, inv, bounds, n.splat(t_min), n.load(t_max)).1
    }

    /// Ray `k`'s [`SlabRay`], `origin` its origin.
    #[inline(always)]
    pub(crate) fn lane(&self, k: usize, origin: DVec3) -> SlabRay {
        let inv = &self.inv;
        SlabRay {
            origin,
            inv_dir: DVec3::new(inv[0][k], inv[1][k], inv[2][k]),
        }
    }
}

/// `if x < y { x } else { y }`: `minsd` (`minpd` in lanes), a single instruction.
#[inline(always)]
fn slab_min<A: Arith>(a: A, x: A::N, y: A::N) -> A::N {
    a.pick_gt(y, x, x, y)
}

/// `if x > y { x } else { y }`: `maxsd` (`maxpd` in lanes), a single instruction.
#[inline(always)]
fn slab_max<A: Arith>(a: A, x: A::N, y: A::N) -> A::N {
    a.pick_gt(x, y, x, y)
}

/// A ray prepared for many slab tests: its origin and reciprocal direction.
#[derive(Debug, Clone, Copy)]
pub struct SlabRay {
    origin: DVec3,
    inv_dir: DVec3,
}

impl SlabRay {
    /// Prepares `origin + λ dir`, a zero direction component replaced by a tiny one
    /// of the same sign (see `nonzero`).
    #[inline]
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        Self {
            origin,
            inv_dir: DVec3::new(
                1.0 / nonzero(dir.x),
                1.0 / nonzero(dir.y),
                1.0 / nonzero(dir.z),
            ),
        }
    }

    /// The entry `λ` of the ray into `[min, max]` clipped to `[t_min, t_max]`, if it enters.
    #[inline(always)]
    pub fn enter(&self, min: DVec3, max: DVec3, t_min: f64, t_max: f64) -> Option<f64> {
        let (near, enters) = slab_enter(
            One,
            self.origin.to_array(),
            self.inv_dir.to_array(),
            (min, max),
            t_min,
            t_max,
        );
        (enters == 1).then_some(near)
    }

    /// [`SlabRay::enter`] for two boxes at once, given axis by axis (`min[axis][box]`).
    #[inline(always)]
    pub fn enter2(
        &self,
        min: &[[f64; 2]; 3],
        max: &[[f64; 2]; 3],
        t_min: f64,
        t_max: f64,
    ) -> (Option<f64>, Option<f64>) {
        let (near, far) = self.slabs2(min, max, t_min, t_max);
        let up = 1.0 + 4.0 * f64::EPSILON;
        (
            (near[0] <= far[0] * up).then_some(near[0]),
            (near[1] <= far[1] * up).then_some(near[1]),
        )
    }

    /// Entry and exit `λ` of both boxes, two lanes at a time. `fast_min`/`fast_max` are
    /// `minpd`/`maxpd` on x86-64, exactly `slab_min` and `slab_max` (no NaN arises
    /// here).
    #[inline(always)]
    fn slabs2(
        &self,
        min: &[[f64; 2]; 3],
        max: &[[f64; 2]; 3],
        t_min: f64,
        t_max: f64,
    ) -> ([f64; 2], [f64; 2]) {
        let o = [self.origin.x, self.origin.y, self.origin.z];
        let inv = [self.inv_dir.x, self.inv_dir.y, self.inv_dir.z];
        let mut near = f64x2::splat(t_min);
        let mut far = f64x2::splat(t_max);
        for a in 0..3 {
            let (oa, ia) = (f64x2::splat(o[a]), f64x2::splat(inv[a]));
            let t0 = (f64x2::new(min[a]) - oa) * ia;
            let t1 = (f64x2::new(max[a]) - oa) * ia;
            near = near.fast_max(t0.fast_min(t1));
            far = far.fast_min(t0.fast_max(t1));
        }
        (near.to_array(), far.to_array())
    }
}

/// A box in single precision, rounded outward from its double-precision bounds (so it
/// only grows): `[min x, min y, min z, max x, max y, max z]`. A coordinate beyond ±10³⁰
/// is pushed out to that bound or to infinity, so that no slab distance of
/// [`SlabRay4::enter`] overflows in its subtraction.
pub type Box32 = [f32; 6];

/// `b` as a [`Box32`].
pub fn box32(b: &Aabb) -> Box32 {
    let lo = |x: f64| {
        if x < -SINGLE_LIMIT {
            f32::NEG_INFINITY
        } else {
            round_down(x.min(SINGLE_LIMIT))
        }
    };
    let hi = |x: f64| {
        if x > SINGLE_LIMIT {
            f32::INFINITY
        } else {
            round_up(x.max(-SINGLE_LIMIT))
        }
    };
    [
        lo(b.min.x),
        lo(b.min.y),
        lo(b.min.z),
        hi(b.max.x),
        hi(b.max.y),
        hi(b.max.z),
    ]
}

/// Both children's boxes of an inner node in single precision, each as [`box32`] makes
/// it, axis by axis with the two children side by side (`min[axis][child]`), so that
/// one 64-bit load reads a coordinate of both.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(8))]
pub struct BoxPair32 {
    /// `min[axis][child]`.
    pub min: [[f32; 2]; 3],
    /// `max[axis][child]`.
    pub max: [[f32; 2]; 3],
}

impl BoxPair32 {
    /// Boxes `a` and `b`, rounded outward.
    pub fn new(a: &Aabb, b: &Aabb) -> BoxPair32 {
        let (a, b) = (box32(a), box32(b));
        BoxPair32 {
            min: [0, 1, 2].map(|k| [a[k], b[k]]),
            max: [3, 4, 5].map(|k| [a[k], b[k]]),
        }
    }

    /// Child `c`'s box.
    #[inline(always)]
    pub fn child(&self, c: usize) -> Box32 {
        [
            self.min[0][c],
            self.min[1][c],
            self.min[2][c],
            self.max[0][c],
            self.max[1][c],
            self.max[2][c],
        ]
    }
}

/// Four rays tested against both children of an inner node: what a packet's traversal
/// asks of its rays, in four lanes ([`SlabRay4`]) or, where the processor has them,
/// eight ([`x86::SlabRay8`]). Every implementation gives exactly what two calls of
/// [`SlabRay4::enter`] give, bit for bit, so the traversal is the same whichever runs.
pub trait PairTest {
    /// [`SlabRay4::enter`] for each child of `b`, each ray within `[t_min, t_max]`
    /// of its lane (`t_max` rounded to the nearest `f32`, as [`lanes`] rounds it).
    fn enter_pair(&self, b: &BoxPair32, t_min: f32, t_max: f32x4) -> [(u32, f32x4); 2];
}

impl PairTest for SlabRay4 {
    #[inline(always)]
    fn enter_pair(&self, b: &BoxPair32, t_min: f32, t_max: f32x4) -> [(u32, f32x4); 2] {
        let t_min = f32x4::splat(t_min);
        [0, 1].map(|c| self.enter(&b.child(c), t_min, t_max))
    }
}

/// Eight rays tested against both children of an inner node: what a packet of eight
/// asks of its rays, as two packets of four (`[P; 2]`, ray `r` in half `r / 4`) or,
/// where the processor has AVX-512, in sixteen lanes ([`x86::SlabRay16`]). Every
/// implementation gives exactly what [`SlabRay4::enter`] gives each half, bit for
/// bit: bit `r` of child `c`'s mask where ray `r` enters it, and its entry `λ` in lane
/// `r`.
pub trait PairTest8 {
    /// [`PairTest::enter_pair`] for the eight rays, their limits rounded as [`lanes8`]
    /// rounds them.
    fn enter_pair8(&self, b: &BoxPair32, t_min: f32, t_max: f32x8) -> [(u32, f32x8); 2];
}

impl<P: PairTest> PairTest8 for [P; 2] {
    #[inline(always)]
    fn enter_pair8(&self, b: &BoxPair32, t_min: f32, t_max: f32x8) -> [(u32, f32x8); 2] {
        let [lo, hi]: [f32x4; 2] = bytemuck::cast(t_max);
        let (lo, hi) = (
            self[0].enter_pair(b, t_min, lo),
            self[1].enter_pair(b, t_min, hi),
        );
        [0, 1].map(|c| (lo[c].0 | hi[c].0 << 4, bytemuck::cast([lo[c].1, hi[c].1])))
    }
}

/// The first four and the last four of eight.
#[inline(always)]
pub fn halves<T>(x: &[T; 8]) -> (&[T; 4], &[T; 4]) {
    let [lo @ .., _, _, _, _] = x;
    let [_, _, _, _, hi @ ..] = x;
    (lo, hi)
}

/// The lanes of eight rays whose entry `λ` (as [`PairTest8::enter_pair8`] gives it) is
/// at most their `t_max` (rounded to the nearest `f32`, as [`lanes8`] rounds it),
/// rounding forgiven: a traversal pops a subtree only for rays that may still find
/// something nearer, or tied, in it.
#[inline(always)]
pub fn within8(near: f32x8, t_max: f32x8) -> u32 {
    near.simd_le(t_max * f32x8::splat(GROW)).to_bitmask()
}

/// The largest `f32` at most `x`, for `x` within `f32`'s finite range.
///
/// Without branches (a lone ray rounds its origin both ways, and which way `as` went is
/// a coin toss): where `x as f32` came out above `x`, one step down on its bits, −1
/// for a positive number and +1 for a negative one (a rounded-up `+0` cannot arise:
/// `x as f32` keeps the sign of `x`).
#[inline(always)]
fn round_down(x: f64) -> f32 {
    let y = x as f32;
    let bits = y.to_bits();
    let negative = bits >> 31;
    let step = (negative << 1).wrapping_sub(1);
    f32::from_bits(bits.wrapping_add(((y as f64) > x) as u32 * step))
}

/// The smallest `f32` at least `x`, for `x` within `f32`'s finite range: as
/// [`round_down`], one step up where `x as f32` came out below `x`.
#[inline(always)]
fn round_up(x: f64) -> f32 {
    let y = x as f32;
    let bits = y.to_bits();
    let negative = bits >> 31;
    let step = 1u32.wrapping_sub(negative << 1);
    f32::from_bits(bits.wrapping_add(((y as f64) < x) as u32 * step))
}

/// Origin coordinates, and the magnitudes of direction components, within which the
/// single-precision test is exact up to relative rounding (see [`SlabRay4::new`]).
const SINGLE_LIMIT: f64 = 1e30;

/// Scales entry distances down, and exit distances up, by more than the relative
/// rounding of a single-precision slab distance (at most 2⁻²⁴ each for the direction
/// rounded to `f32`, its reciprocal, the subtraction, the product, and `t_min` or
/// `t_max` rounded to `f32`: five in all), so that the test never rejects a box a ray
/// enters: 2⁻²⁰, sixteen of them, leaves a wide margin.
const SHRINK: f32 = 1.0 - 1.0 / (1u32 << 20) as f32;
const GROW: f32 = 1.0 + 1.0 / (1u32 << 20) as f32;

/// The magnitudes a direction component, rounded to `f32`, may have for the
/// single-precision test (see [`SlabRay4::new`]).
const DIR_SMALLEST: f32 = 1e-30;
const DIR_LARGEST: f32 = 1e30;

/// Whether every direction component of every lane, rounded to `f32`, is of magnitude
/// within [`DIR_SMALLEST`, `DIR_LARGEST`]; written so that a NaN fails too.
#[inline(always)]
fn fits(d: &[f32x4; 3]) -> bool {
    let (small, large) = (f32x4::splat(DIR_SMALLEST), f32x4::splat(DIR_LARGEST));
    d.iter().all(|d| {
        let m = d.abs();
        (m.simd_ge(small) & m.simd_le(large)).to_bitmask() == 0b1111
    })
}

/// Whether an origin coordinate is within the single-precision test's range.
#[inline(always)]
fn near(o: f64) -> bool {
    o.abs() <= SINGLE_LIMIT
}

/// Four rays prepared for slab tests together, a SIMD lane each, in single precision:
/// a packet of neighbouring primary rays traverses a BVH once for all four.
///
/// Each ray's origin is taken as two `f32`s, one rounded down and one up. A slab's
/// distances are `(min − o_up) / d` and `(max − o_down) / d`: whatever the sign of `d`,
/// the smaller is at most the true entry and the larger at least the true exit, so the
/// only error left is the relative rounding of the direction, its reciprocal, the
/// subtraction and the product, which `SHRINK` and `GROW` cover.
#[derive(Debug, Clone, Copy)]
pub struct SlabRay4 {
    o_down: [f32x4; 3],
    o_up: [f32x4; 3],
    inv: [f32x4; 3],
}

impl SlabRay4 {
    /// Prepares four rays, or `None` when some coordinate of an origin is beyond ±10³⁰
    /// or some direction component, rounded to `f32`, is zero or of magnitude outside
    /// [10⁻³⁰, 10³⁰]: then every distance is a normal `f32` or an overflow to the
    /// right infinity, and no `0 · ∞` arises. Such rays are traced one at a time.
    // Always inlined: returned through an `Option`, the prepared rays were copied by a
    // call to `memcpy` after each call.
    #[inline(always)]
    pub fn new(rays: &[Ray; 4]) -> Option<SlabRay4> {
        let first = rays[0].origin;
        SlabRay4::new_from(rays, rays.iter().all(|r| r.origin == first))
    }

    /// [`SlabRay4::new`], `shared` saying that the caller knows every ray to start at
    /// the first one's origin (a camera's rays), so that the origins are not compared:
    /// rounded once, as they are for rays found to share it. False takes each ray's
    /// own origin, which gives the same numbers for rays that do share one.
    #[inline(always)]
    pub fn new_from(rays: &[Ray; 4], shared: bool) -> Option<SlabRay4> {
        let mut d = [[0f32; 4]; 3];
        for (lane, r) in rays.iter().enumerate() {
            for (a, axis) in d.iter_mut().enumerate() {
                axis[lane] = r.dir[a] as f32;
            }
        }
        let d = d.map(f32x4::new);
        if shared {
            // Primary rays share the camera: its bounds once.
            return SlabRay4::shared(d, d.map(|d| f32x4::splat(1.0) / d), rays[0].origin);
        }
        if !fits(&d) {
            return None;
        }
        // Axis by axis over the four lanes, refused once at the end, so that the lanes
        // are rounded side by side in vector registers; one lane's early return made
        // each coordinate a branch. A coordinate out of range rounds to a number that
        // is never used.
        let mut down = [[0f32; 4]; 3];
        let mut up = [[0f32; 4]; 3];
        let mut far = false;
        for a in 0..3 {
            // Indexed, not `rays.map`: that copied the four rays for each axis.
            let o: [f64; 4] = std::array::from_fn(|k| rays[k].origin[a]);
            far |= !o.iter().all(|&o| near(o));
            down[a] = o.map(round_down);
            up[a] = o.map(round_up);
        }
        if far {
            return None;
        }
        Some(SlabRay4 {
            o_down: down.map(f32x4::new),
            o_up: up.map(f32x4::new),
            inv: d.map(|d| f32x4::splat(1.0) / d),
        })
    }

    /// Eight rays as two packets of four (the first four, the last four), or `None`
    /// where either half is refused ([`SlabRay4::new`]).
    #[inline(always)]
    pub fn pair(rays: &[Ray; 8]) -> Option<[SlabRay4; 2]> {
        let (lo, hi) = halves(rays);
        Some([SlabRay4::new(lo)?, SlabRay4::new(hi)?])
    }

    /// [`SlabRay4::pair`] with [`SlabRay4::new_from`]'s `shared`.
    #[inline(always)]
    pub fn pair_from(rays: &[Ray; 8], shared: bool) -> Option<[SlabRay4; 2]> {
        let (lo, hi) = halves(rays);
        Some([
            SlabRay4::new_from(lo, shared)?,
            SlabRay4::new_from(hi, shared)?,
        ])
    }

    /// One ray in all four lanes, as [`SlabRay4::new`] makes four copies of it: for
    /// testing four boxes at once ([`SlabRay4::enter_lanes`]), at a third of the cost
    /// of gathering four rays.
    #[inline]
    pub fn splat(ray: &Ray) -> Option<SlabRay4> {
        let d = ray.dir.to_array().map(|d| d as f32);
        // The three axes' reciprocals in one division, each then in every lane: the
        // same numbers as dividing each axis's four copies, in a third of the divisions
        // (a lone shadow ray through a wide tree makes them where the processor has no
        // AVX2; `Avx2::wide_ray` gives these numbers too).
        let [x, y, z, _] = (f32x4::splat(1.0) / f32x4::new([d[0], d[1], d[2], 1.0])).to_array();
        SlabRay4::shared(d.map(f32x4::splat), [x, y, z].map(f32x4::splat), ray.origin)
    }

    /// Rays of directions `d` (axis by axis, as `f32`) from one `origin`, `inv` their
    /// reciprocals.
    #[inline(always)]
    fn shared(d: [f32x4; 3], inv: [f32x4; 3], origin: DVec3) -> Option<SlabRay4> {
        if !(fits(&d) && near(origin.x) && near(origin.y) && near(origin.z)) {
            return None;
        }
        let (x, y, z) = (origin.x, origin.y, origin.z);
        Some(SlabRay4 {
            o_down: [round_down(x), round_down(y), round_down(z)].map(f32x4::splat),
            o_up: [round_up(x), round_up(y), round_up(z)].map(f32x4::splat),
            inv,
        })
    }

    /// Tests box `b` for the four rays, each within `[t_min, t_max]` of its lane
    /// (`t_min ≥ 0`): a bit per ray that enters, and each ray's entry `λ` rounded down
    /// (a lower bound, so a traversal that skips a box entered beyond the best `λ`
    /// never skips one it must see). Never rejects a box that a ray meets within its
    /// interval, grazing its faces, edges and corners included.
    #[inline(always)]
    pub fn enter(&self, b: &Box32, t_min: f32x4, t_max: f32x4) -> (u32, f32x4) {
        self.enter_lanes(&b.map(f32x4::splat), t_min, t_max)
    }

    /// [`SlabRay4::enter`] with a box in each lane: `planes[k]` holds coordinate `k`
    /// of lane `r`'s box in [`Box32`]'s order. Four rays against one box each; one ray
    /// in every lane against four boxes ([`Bvh::any`](super::bvh::Bvh::any)).
    #[inline(always)]
    pub fn enter_lanes(&self, planes: &[f32x4; 6], t_min: f32x4, t_max: f32x4) -> (u32, f32x4) {
        let mut near = t_min;
        let mut far = t_max;
        for a in 0..3 {
            let t0 = (planes[a] - self.o_up[a]) * self.inv[a];
            let t1 = (planes[a + 3] - self.o_down[a]) * self.inv[a];
            // No NaN arises (see `new`): `minps`/`maxps` are exact here.
            near = near.fast_max(t0.fast_min(t1));
            far = far.fast_min(t0.fast_max(t1));
        }
        let near = near * f32x4::splat(SHRINK);
        let hit = near.simd_le(far * f32x4::splat(GROW));
        (hit.to_bitmask(), near)
    }
}

/// A lone ray's test of a wide node's eight boxes ([`Bvh::any`](super::bvh::Bvh::any)):
/// `planes[k][c]` holds coordinate `k` of child `c`'s box in [`Box32`]'s order; a bit
/// per box the ray enters within `[t_min, t_max]`. Every implementation makes
/// [`SlabRay4::enter_lanes`]'s operations lane for lane, so the bits are the same.
pub trait WideTest {
    /// The bit set of the eight boxes entered.
    fn enter_wide(&self, planes: &[[f32; 8]; 6], t_min: f32, t_max: f32) -> u32;
}

impl WideTest for SlabRay4 {
    /// Two passes of four lanes, the ray (made by [`SlabRay4::splat`]) in each.
    #[inline(always)]
    fn enter_wide(&self, planes: &[[f32; 8]; 6], t_min: f32, t_max: f32) -> u32 {
        let (t_min, t_max) = (f32x4::splat(t_min), f32x4::splat(t_max));
        let half = |h: usize| {
            planes.map(|p| f32x4::new([p[4 * h], p[4 * h + 1], p[4 * h + 2], p[4 * h + 3]]))
        };
        self.enter_lanes(&half(0), t_min, t_max).0 | self.enter_lanes(&half(1), t_min, t_max).0 << 4
    }
}

/// The lanes set in a packet's bit set, lowest first.
#[inline(always)]
pub fn lanes_of(mut bits: u32) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (bits != 0).then(|| {
            let lane = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            lane
        })
    })
}

/// The lanes of `bits` for which `each(lane)` holds, as a bit set.
#[inline(always)]
pub fn lanes_where(bits: u32, mut each: impl FnMut(usize) -> bool) -> u32 {
    let mut out = 0;
    for lane in lanes_of(bits) {
        out |= (each(lane) as u32) << lane;
    }
    out
}

/// `each(lane)` for the lanes of `bits`, `T::default()` in the others: a packet's
/// rays taken one at a time.
#[inline(always)]
pub fn per_lane<T: Copy + Default, const N: usize>(
    bits: u32,
    mut each: impl FnMut(usize) -> T,
) -> [T; N] {
    let mut out = [T::default(); N];
    for lane in lanes_of(bits) {
        out[lane] = each(lane);
    }
    out
}

/// `t` for each of four rays, as the `f32` lanes [`SlabRay4::enter`] takes.
#[inline(always)]
pub fn lanes(t: &[f64; 4]) -> f32x4 {
    f32x4::new(t.map(|x| x as f32))
}

/// [`lanes`] for eight limits, four at a time.
#[inline(always)]
pub fn lanes8(t: &[f64; 8]) -> f32x8 {
    let (lo, hi) = halves(t);
    bytemuck::cast([lanes(lo), lanes(hi)])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_enters_box_ahead() {
        let r = SlabRay::new(DVec3::new(0.0, 0.0, -5.0), DVec3::Z);
        assert_eq!(
            r.enter(DVec3::splat(-1.0), DVec3::splat(1.0), 0.0, f64::INFINITY),
            Some(4.0)
        );
        assert_eq!(
            r.enter(DVec3::splat(-1.0), DVec3::splat(1.0), 0.0, 3.0),
            None
        );
    }

    #[test]
    fn slab_keeps_ray_along_a_padded_face() {
        // A ray with Δx = 0 running along the face x = 1 of a shape: the padded box
        // still holds it, and no NaN appears.
        let r = SlabRay::new(DVec3::new(1.0, 0.0, -5.0), DVec3::Z);
        let b = Aabb::CANONICAL.padded();
        let t = r.enter(b.min, b.max, 0.0, f64::INFINITY).expect("enters");
        assert!(t > 3.9 && t < 4.0);
        let outside = SlabRay::new(DVec3::new(1.5, 0.0, -5.0), DVec3::Z);
        assert!(outside.enter(b.min, b.max, 0.0, f64::INFINITY).is_none());
    }

    #[test]
    fn single_precision_boxes_only_grow() {
        let b = Aabb {
            min: DVec3::new(0.1, -1e-40, -3e35),
            max: DVec3::new(0.3, 1e-300, 7e31),
        };
        let f = box32(&b);
        for a in 0..3 {
            assert!(
                (f[a] as f64) <= b.min[a],
                "axis {a}: {} > {}",
                f[a],
                b.min[a]
            );
            assert!(
                (f[a + 3] as f64) >= b.max[a],
                "axis {a}: {} < {}",
                f[a + 3],
                b.max[a]
            );
        }
        // Beyond ±1e30 a coordinate goes out to infinity, or in to the bound.
        assert_eq!((f[2], f[5]), (f32::NEG_INFINITY, f32::INFINITY));
        let far = box32(&Aabb {
            min: DVec3::splat(2e30),
            max: DVec3::splat(-2e30),
        });
        assert!(far[0] as f64 <= 1e30 && far[3] as f64 >= -1e30);
        // One step outward where f32 cannot hold the value, none where it can.
        assert_eq!((f[0], f[3]), (0.1f32.next_down(), 0.3f32));
        assert_eq!(box32(&Aabb::CANONICAL), [-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]);
    }

    fn ray(o: [f64; 3], d: [f64; 3]) -> Ray {
        Ray::new(DVec3::from(o), DVec3::from(d))
    }

    #[test]
    fn packets_refuse_rays_the_single_precision_test_cannot_bound() {
        let good = ray([0.0, 1.0, -5.0], [0.3, -0.2, 1.0]);
        assert!(SlabRay4::new(&[good; 4]).is_some());
        for bad in [
            ray([0.0, 1.0, -5.0], [0.0, -0.2, 1.0]),
            ray([0.0, 1.0, -5.0], [1e-31, -0.2, 1.0]),
            ray([0.0, 1.0, -5.0], [1e31, -0.2, 1.0]),
            ray([0.0, 1.0, -5.0], [f64::NAN, -0.2, 1.0]),
            ray([2e30, 1.0, -5.0], [0.3, -0.2, 1.0]),
            ray([f64::NAN, 1.0, -5.0], [0.3, -0.2, 1.0]),
            ray([0.0, 1.0, -3e30], [0.3, -0.2, 1.0]),
        ] {
            // In any lane: the lanes are rounded together and refused at the end.
            for lane in 0..4 {
                let mut rays = [good; 4];
                rays[lane] = bad;
                assert!(SlabRay4::new(&rays).is_none(), "{bad:?} in lane {lane}");
            }
            assert!(SlabRay4::new(&[bad; 4]).is_none(), "{bad:?}");
        }
    }

    #[test]
    fn a_packet_enters_what_each_ray_enters_and_no_later() {
        // A box the rays graze: one runs just under its top face, one touches its edge.
        let b = Aabb {
            min: DVec3::new(-1.0, -1.0, 2.0),
            max: DVec3::new(1.0, 1.0, 4.0),
        };
        let rays = [
            ray([0.0, 0.0, 0.0], [0.1, 0.1, 1.0]),
            ray([0.0, 1.0, 0.0], [0.1, -1e-20, 1.0]),
            ray([0.0, 0.0, 0.0], [0.5, 0.5, 1.0]),
            ray([0.0, 0.0, 0.0], [0.6, 0.1, 1.0]),
        ];
        let p = SlabRay4::new(&rays).expect("a packet");
        let (hit, near) = p.enter(&box32(&b), f32x4::splat(0.0), f32x4::splat(f32::INFINITY));
        // Lane 2 touches the edge x = y = 1 at z = 2 (λ = 2); lane 3 leaves through
        // x = 1 at λ = 1.67, before z = 2.
        assert_eq!(hit, 0b0111);
        let near = near.to_array();
        for (lane, &t) in near.iter().enumerate().take(3) {
            let t = t as f64;
            assert!(t <= 2.0 && t > 2.0 * 0.999_99, "lane {lane}: {t}");
        }
        // A ray whose best so far is before the box does not enter it.
        let (hit, _) = p.enter(
            &box32(&b),
            f32x4::splat(0.0),
            f32x4::new([1.9, 1e9, 1.5, 1e9]),
        );
        assert_eq!(hit, 0b0010);
        assert_eq!(
            within8(
                f32x8::splat(2.0),
                lanes8(&[1.0, 2.0, 3.0, 1.999_999_9, 1.0, 2.0, 3.0, 1.999_999_9])
            ),
            0b1110_1110
        );
    }

    /// The rounding by `next_down`/`next_up`, with branches: the reference for the
    /// branch-free bit steps.
    fn rounded(x: f64) -> (f32, f32) {
        let y = x as f32;
        (
            if y as f64 > x { y.next_down() } else { y },
            if (y as f64) < x { y.next_up() } else { y },
        )
    }

    #[test]
    fn rounding_both_ways_steps_across_zero_and_subnormals() {
        let tiny = f32::from_bits(1) as f64;
        for x in [
            0.0,
            -0.0,
            tiny / 4.0,
            -tiny / 4.0,
            tiny,
            -tiny,
            tiny * 1.5,
            f32::MIN_POSITIVE as f64 * (1.0 + 1e-9),
            0.1,
            -0.1,
            1.0,
            -1.0,
            1.0 + 1e-12,
            -(1.0 + 1e-12),
            1e30,
            -1e30,
            f64::NAN,
        ] {
            let (down, up) = (round_down(x), round_up(x));
            let (rd, ru) = rounded(x);
            assert_eq!(
                (down.to_bits(), up.to_bits()),
                (rd.to_bits(), ru.to_bits()),
                "{x:e}"
            );
            if !x.is_nan() {
                assert!(down as f64 <= x && up as f64 >= x, "{x:e}");
            }
        }
    }

    #[test]
    fn a_splat_ray_is_four_copies_of_it() {
        for r in [
            ray([0.1, 1.0, -5.0], [0.3, -0.2, 1.0]),
            ray([-3.3, 1e-3, 7.25], [-1e-3, 0.9, -0.4]),
            ray([0.0, 1.0, -5.0], [0.0, -0.2, 1.0]),
            ray([2e30, 1.0, -5.0], [0.3, -0.2, 1.0]),
        ] {
            let (one, four) = (SlabRay4::splat(&r), SlabRay4::new(&[r; 4]));
            assert_eq!(one.is_some(), four.is_some(), "{r:?}");
            if let (Some(one), Some(four)) = (one, four) {
                assert_eq!(format!("{one:?}"), format!("{four:?}"));
            }
        }
    }

    use proptest::prelude::*;

    /// A direction component of any size, zeros of both signs and subnormals included.
    fn component() -> impl Strategy<Value = f64> {
        prop_oneof![
            -10.0f64..10.0,
            -1e-30f64..1e-30,
            Just(0.0),
            Just(-0.0),
            Just(1e-310),
            Just(-1e-320),
            -1e35f64..1e35,
            proptest::num::f64::NORMAL,
        ]
    }

    proptest! {
        /// A lone ray's four-lane form, its reciprocals found in one division, is four
        /// copies of the ray as a packet makes them, lane by lane.
        #[test]
        fn any_splat_ray_is_four_copies_of_it(
            o in prop::array::uniform3(-100.0f64..100.0),
            d in prop::array::uniform3(component()),
        ) {
            let r = ray(o, d);
            let (one, four) = (SlabRay4::splat(&r), SlabRay4::new(&[r; 4]));
            prop_assert_eq!(one.is_some(), four.is_some());
            if let (Some(one), Some(four)) = (one, four) {
                prop_assert_eq!(format!("{one:?}"), format!("{four:?}"));
            }
        }

        /// Eight rays prepared together, in either kind of lanes, are each the ray
        /// [`SlabRay::new`] prepares, bit for bit (directions of every size, zeros of
        /// both signs and subnormals included, where a tiny stand-in replaces the
        /// component), and enter a box exactly where [`SlabRay::enter`] says they do,
        /// each within its own limit (infinite, zero, or NaN too).
        #[test]
        fn eight_rays_prepared_together_are_each_the_lone_ray(
            o in prop::array::uniform8(prop::array::uniform3(-100.0f64..100.0)),
            d in prop::array::uniform8(prop::array::uniform3(component())),
            corners in prop::array::uniform2(prop::array::uniform3(-50.0f64..50.0)),
            t_min in prop_oneof![Just(0.0), 0.0f64..1.0],
            t_max in prop::array::uniform8(prop_oneof![
                Just(f64::INFINITY),
                Just(0.0),
                Just(f64::NAN),
                0.0f64..200.0,
            ]),
        ) {
            let rays: [Ray; 8] = std::array::from_fn(|k| ray(o[k], d[k]));
            let eight = Rays8::from_rays(&rays);
            let (a, b) = (DVec3::from_array(corners[0]), DVec3::from_array(corners[1]));
            let (min, max) = (a.min(b), a.max(b));
            let check = |slabs: SlabRays8, enters: u32| -> Result<(), TestCaseError> {
                for (k, r) in rays.iter().enumerate() {
                    let (lone, lane) = (SlabRay::new(r.origin, r.dir), slabs.lane(k, r.origin));
                    let bits = |v: DVec3| v.to_array().map(f64::to_bits);
                    prop_assert_eq!(bits(lane.inv_dir), bits(lone.inv_dir), "ray {}", k);
                    prop_assert_eq!(bits(lane.origin), bits(lone.origin));
                    let alone = lone.enter(min, max, t_min, t_max[k]).is_some();
                    prop_assert_eq!(enters >> k & 1 == 1, alone, "ray {} enters", k);
                }
                Ok(())
            };
            let n = Eight(crate::geometry::arith::Portable);
            let slabs = SlabRays8::new(n, &eight);
            check(slabs, slabs.enter8(n, &eight, (min, max), t_min, &t_max))?;
            #[cfg(target_arch = "x86_64")]
            if let Some(avx2) = x86::Avx2::detect() {
                let n = Eight(avx2);
                let (slabs, enters) = avx2.run(|| {
                    let slabs = SlabRays8::new(n, &eight);
                    (slabs, slabs.enter8(n, &eight, (min, max), t_min, &t_max))
                });
                check(slabs, enters)?;
            }
        }

        #[test]
        fn rounding_both_ways_is_next_down_and_next_up(
            x in prop_oneof![
                -1e30f64..1e30,
                -1e-30f64..1e-30,
                -1e-44f64..1e-44,
                proptest::num::f32::ANY.prop_map(f64::from),
            ]
        ) {
            let (rd, ru) = rounded(x);
            prop_assert_eq!(round_down(x).to_bits(), rd.to_bits());
            prop_assert_eq!(round_up(x).to_bits(), ru.to_bits());
        }
    }

    #[test]
    fn transformed_box_holds_corners() {
        let m = DAffine3::from_rotation_y(0.7) * DAffine3::from_translation(DVec3::X);
        let b = Aabb::CANONICAL.transformed(&m);
        for c in [
            DVec3::splat(1.0),
            DVec3::splat(-1.0),
            DVec3::new(1.0, -1.0, 1.0),
        ] {
            let p = m.transform_point3(c);
            assert!(p.cmpge(b.min).all() && p.cmple(b.max).all());
        }
    }
}
