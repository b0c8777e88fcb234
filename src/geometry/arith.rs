//! Arithmetic in lanes that gives each lane the bits one number alone would have:
//! four f64 lanes ([`Lanes4`]), and a formula written once for one number or eight
//! lanes (`Arith`): generic over it, a formula computes a lone ray's or hit's numbers
//! in `One` (or a lone ray's three axes side by side in `Four`) and a packet's in
//! `Eight`, every step the same IEEE operation in the same order (no fused steps,
//! choices instead of `f64::max`, whose sign of a zero is the compiler's), so each lane
//! is the lone number bit for bit. The light terms (`render::shade::light`), a packet's
//! tests of the shapes other than a mesh (`shapes::Shape::intersect_in_lanes8`, and a
//! plane's `shapes::plane::lambdas_from_y`) and the carrying of rays into an object's
//! space (`Ray::transformed`) are written over it.

use std::ops::{Add, Div, Mul, Sub};

use glam::{DAffine3, DMat3, DVec3};
use wide::f64x4;

/// Arithmetic in four f64 lanes, each lane by the same operations as one number alone
/// (no fused steps), so the same bits: [`Portable`] everywhere, and one AVX register
/// ([`Avx2`](super::bounds::x86::Avx2)) where the processor has AVX2, half the
/// instructions. Comparisons give the bit set of the lanes where they hold.
pub trait Lanes4: Copy {
    /// Four lanes.
    type V: Copy
        + Add<Output = Self::V>
        + Sub<Output = Self::V>
        + Mul<Output = Self::V>
        + Div<Output = Self::V>;
    /// `x` in every lane.
    fn splat(self, x: f64) -> Self::V;
    /// The lanes of `x`.
    fn load(self, x: &[f64; 4]) -> Self::V;
    /// The lanes as an array.
    fn store(self, v: Self::V) -> [f64; 4];
    /// Where `a ≥ b` (not where either is NaN).
    fn ge(self, a: Self::V, b: Self::V) -> u32;
    /// Where `a > b` (not where either is NaN).
    fn gt(self, a: Self::V, b: Self::V) -> u32;
    /// Where `a ≤ b` (not where either is NaN).
    fn le(self, a: Self::V, b: Self::V) -> u32;
    /// Where `a ≠ b` (and where either is NaN).
    fn ne(self, a: Self::V, b: Self::V) -> u32;
    /// The square root of each lane.
    fn sqrt(self, a: Self::V) -> Self::V;
    /// Each lane's magnitude (its sign bit cleared, as `f64::abs`).
    fn abs(self, a: Self::V) -> Self::V;
    /// `x` where `a > b`, else `y` (where either is NaN too), lane by lane.
    fn pick_gt(self, a: Self::V, b: Self::V, x: Self::V, y: Self::V) -> Self::V;
}

/// [`Lanes4`] in two SSE2 registers (the `wide` crate's `f64x4`), on any processor.
#[derive(Debug, Clone, Copy)]
pub struct Portable;

impl Lanes4 for Portable {
    type V = f64x4;

    #[inline(always)]
    fn splat(self, x: f64) -> f64x4 {
        f64x4::splat(x)
    }

    #[inline(always)]
    fn load(self, x: &[f64; 4]) -> f64x4 {
        f64x4::new(*x)
    }

    #[inline(always)]
    fn store(self, v: f64x4) -> [f64; 4] {
        v.to_array()
    }

    #[inline(always)]
    fn ge(self, a: f64x4, b: f64x4) -> u32 {
        a.simd_ge(b).to_bitmask()
    }

    #[inline(always)]
    fn gt(self, a: f64x4, b: f64x4) -> u32 {
        a.simd_gt(b).to_bitmask()
    }

    #[inline(always)]
    fn le(self, a: f64x4, b: f64x4) -> u32 {
        a.simd_le(b).to_bitmask()
    }

    #[inline(always)]
    fn ne(self, a: f64x4, b: f64x4) -> u32 {
        a.simd_ne(b).to_bitmask()
    }

    #[inline(always)]
    fn sqrt(self, a: f64x4) -> f64x4 {
        a.sqrt()
    }

    #[inline(always)]
    fn abs(self, a: f64x4) -> f64x4 {
        a.abs()
    }

    #[inline(always)]
    fn pick_gt(self, a: f64x4, b: f64x4, x: f64x4, y: f64x4) -> f64x4 {
        a.simd_gt(b).select(x, y)
    }
}

/// Numbers a formula is computed in: one `f64` ([`One`]), or eight lanes
/// ([`Eight`]). A value of the type is the proof its instructions can run, as a
/// [`Lanes4`] is; every method is always inlined, so that it compiles for the
/// instruction sets of the function it is inlined into.
pub(crate) trait Arith: Copy {
    /// One number, or eight.
    type N: Copy;
    /// `x` in every lane.
    fn splat(self, x: f64) -> Self::N;
    /// `a + b`.
    fn add(self, a: Self::N, b: Self::N) -> Self::N;
    /// `a − b`.
    fn sub(self, a: Self::N, b: Self::N) -> Self::N;
    /// `a · b`.
    fn mul(self, a: Self::N, b: Self::N) -> Self::N;
    /// `a / b`.
    fn div(self, a: Self::N, b: Self::N) -> Self::N;
    /// `√a`.
    fn sqrt(self, a: Self::N) -> Self::N;
    /// `|a|`, the sign bit cleared.
    fn abs(self, a: Self::N) -> Self::N;
    /// `−a`, the sign bit flipped (a NaN's sign aside).
    fn neg(self, a: Self::N) -> Self::N;
    /// `x` where `a > b`, else `y` (where either is NaN too).
    fn pick_gt(self, a: Self::N, b: Self::N, x: Self::N, y: Self::N) -> Self::N;
    /// The lanes where `a ≥ b` (not where either is NaN).
    fn ge(self, a: Self::N, b: Self::N) -> u32;
    /// The lanes where `a > b` (not where either is NaN).
    fn gt(self, a: Self::N, b: Self::N) -> u32;
    /// The lanes where `a ≠ b` (and where either is NaN).
    fn ne(self, a: Self::N, b: Self::N) -> u32;

    /// `v` in every lane.
    #[inline(always)]
    fn splat3(self, v: DVec3) -> [Self::N; 3] {
        [self.splat(v.x), self.splat(v.y), self.splat(v.z)]
    }
    /// `a · b`, summed as glam's `dot` sums it.
    #[inline(always)]
    fn dot(self, a: [Self::N; 3], b: [Self::N; 3]) -> Self::N {
        let xy = self.add(self.mul(a[0], b[0]), self.mul(a[1], b[1]));
        self.add(xy, self.mul(a[2], b[2]))
    }
    /// `a · s`.
    #[inline(always)]
    fn scale(self, a: [Self::N; 3], s: Self::N) -> [Self::N; 3] {
        [self.mul(a[0], s), self.mul(a[1], s), self.mul(a[2], s)]
    }
    /// `a + b`.
    #[inline(always)]
    fn add3(self, a: [Self::N; 3], b: [Self::N; 3]) -> [Self::N; 3] {
        [
            self.add(a[0], b[0]),
            self.add(a[1], b[1]),
            self.add(a[2], b[2]),
        ]
    }
    /// `a − b`.
    #[inline(always)]
    fn sub3(self, a: [Self::N; 3], b: [Self::N; 3]) -> [Self::N; 3] {
        [
            self.sub(a[0], b[0]),
            self.sub(a[1], b[1]),
            self.sub(a[2], b[2]),
        ]
    }
    /// `a ⊙ b`.
    #[inline(always)]
    fn mul3(self, a: [Self::N; 3], b: [Self::N; 3]) -> [Self::N; 3] {
        [
            self.mul(a[0], b[0]),
            self.mul(a[1], b[1]),
            self.mul(a[2], b[2]),
        ]
    }
    /// Coordinate `k` of `m · v`, `(m₀ₖ v₀ + m₁ₖ v₁) + m₂ₖ v₂` (column `i`, row `k`),
    /// summed as glam's `DMat3::mul_vec3` sums it.
    #[inline(always)]
    fn carry_coordinate(self, m: &DMat3, k: usize, v: [Self::N; 3]) -> Self::N {
        let xy = self.add(
            self.mul(self.splat(m.x_axis[k]), v[0]),
            self.mul(self.splat(m.y_axis[k]), v[1]),
        );
        self.add(xy, self.mul(self.splat(m.z_axis[k]), v[2]))
    }
    /// `m · v` (so `DAffine3`'s `transform_vector3` too): a direction carried into
    /// another space.
    #[inline(always)]
    fn carry_vector(self, m: &DMat3, v: [Self::N; 3]) -> [Self::N; 3] {
        [
            self.carry_coordinate(m, 0, v),
            self.carry_coordinate(m, 1, v),
            self.carry_coordinate(m, 2, v),
        ]
    }
    /// `m · p`, as glam's `DAffine3::transform_point3` computes it: the linear part's
    /// product, then the translation.
    #[inline(always)]
    fn carry_point(self, m: &DAffine3, p: [Self::N; 3]) -> [Self::N; 3] {
        self.add3(self.carry_vector(&m.matrix3, p), self.splat3(m.translation))
    }
    /// `a / |a|`, as glam's `normalize` computes it: `a · (1 / √(a · a))`.
    #[inline(always)]
    fn normalize(self, a: [Self::N; 3]) -> [Self::N; 3] {
        let length = self.sqrt(self.dot(a, a));
        self.scale(a, self.div(self.splat(1.0), length))
    }
}

/// One `f64`: a lone hit's terms.
#[derive(Debug, Clone, Copy)]
pub(crate) struct One;

impl Arith for One {
    type N = f64;

    #[inline(always)]
    fn splat(self, x: f64) -> f64 {
        x
    }
    #[inline(always)]
    fn add(self, a: f64, b: f64) -> f64 {
        a + b
    }
    #[inline(always)]
    fn sub(self, a: f64, b: f64) -> f64 {
        a - b
    }
    #[inline(always)]
    fn mul(self, a: f64, b: f64) -> f64 {
        a * b
    }
    #[inline(always)]
    fn div(self, a: f64, b: f64) -> f64 {
        a / b
    }
    #[inline(always)]
    fn sqrt(self, a: f64) -> f64 {
        a.sqrt()
    }
    #[inline(always)]
    fn abs(self, a: f64) -> f64 {
        a.abs()
    }
    #[inline(always)]
    fn neg(self, a: f64) -> f64 {
        -a
    }
    #[inline(always)]
    fn pick_gt(self, a: f64, b: f64, x: f64, y: f64) -> f64 {
        if a > b { x } else { y }
    }
    #[inline(always)]
    fn ge(self, a: f64, b: f64) -> u32 {
        (a >= b) as u32
    }
    #[inline(always)]
    fn gt(self, a: f64, b: f64) -> u32 {
        (a > b) as u32
    }
    #[inline(always)]
    fn ne(self, a: f64, b: f64) -> u32 {
        (a != b) as u32
    }
}

/// Eight lanes, as two vectors of [`Lanes4`] `L`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Eight<L>(pub(crate) L);

impl<L: Lanes4> Eight<L> {
    /// The lanes of `a`.
    #[inline(always)]
    pub(crate) fn load(self, a: &[f64; 8]) -> [L::V; 2] {
        [
            self.0.load(&[a[0], a[1], a[2], a[3]]),
            self.0.load(&[a[4], a[5], a[6], a[7]]),
        ]
    }

    /// Three coordinates' lanes.
    #[inline(always)]
    pub(crate) fn load3(self, a: &[[f64; 8]; 3]) -> [[L::V; 2]; 3] {
        [self.load(&a[0]), self.load(&a[1]), self.load(&a[2])]
    }

    /// The lanes as an array.
    #[inline(always)]
    pub(crate) fn store(self, a: [L::V; 2]) -> [f64; 8] {
        let (x, y) = (self.0.store(a[0]), self.0.store(a[1]));
        [x[0], x[1], x[2], x[3], y[0], y[1], y[2], y[3]]
    }

    /// `f` of each half.
    #[inline(always)]
    fn each(a: [L::V; 2], b: [L::V; 2], f: impl Fn(L::V, L::V) -> L::V) -> [L::V; 2] {
        [f(a[0], b[0]), f(a[1], b[1])]
    }
}

impl<L: Lanes4> Arith for Eight<L> {
    type N = [L::V; 2];

    #[inline(always)]
    fn splat(self, x: f64) -> Self::N {
        [self.0.splat(x); 2]
    }
    #[inline(always)]
    fn add(self, a: Self::N, b: Self::N) -> Self::N {
        Self::each(
            a,
            b,
            #[inline(always)]
            |a, b| a + b,
        )
    }
    #[inline(always)]
    fn sub(self, a: Self::N, b: Self::N) -> Self::N {
        Self::each(
            a,
            b,
            #[inline(always)]
            |a, b| a - b,
        )
    }
    #[inline(always)]
    fn mul(self, a: Self::N, b: Self::N) -> Self::N {
        Self::each(
            a,
            b,
            #[inline(always)]
            |a, b| a * b,
        )
    }
    #[inline(always)]
    fn div(self, a: Self::N, b: Self::N) -> Self::N {
        Self::each(
            a,
            b,
            #[inline(always)]
            |a, b| a / b,
        )
    }
    #[inline(always)]
    fn sqrt(self, a: Self::N) -> Self::N {
        [self.0.sqrt(a[0]), self.0.sqrt(a[1])]
    }
    #[inline(always)]
    fn abs(self, a: Self::N) -> Self::N {
        [self.0.abs(a[0]), self.0.abs(a[1])]
    }
    #[inline(always)]
    fn neg(self, a: Self::N) -> Self::N {
        // `−0 − a` is `−a` for every number, zeros included (`−0 − 0 = −0`, `−0 − −0 = +0`).
        self.sub(self.splat(-0.0), a)
    }
    #[inline(always)]
    fn pick_gt(self, a: Self::N, b: Self::N, x: Self::N, y: Self::N) -> Self::N {
        [
            self.0.pick_gt(a[0], b[0], x[0], y[0]),
            self.0.pick_gt(a[1], b[1], x[1], y[1]),
        ]
    }
    #[inline(always)]
    fn ge(self, a: Self::N, b: Self::N) -> u32 {
        self.0.ge(a[0], b[0]) | self.0.ge(a[1], b[1]) << 4
    }
    #[inline(always)]
    fn gt(self, a: Self::N, b: Self::N) -> u32 {
        self.0.gt(a[0], b[0]) | self.0.gt(a[1], b[1]) << 4
    }
    #[inline(always)]
    fn ne(self, a: Self::N, b: Self::N) -> u32 {
        self.0.ne(a[0], b[0]) | self.0.ne(a[1], b[1]) << 4
    }
}

/// Four lanes, one vector of [`Lanes4`] `L`: a lone ray's numbers of three axes (and a
/// spare lane) computed side by side, as the cube's faces are.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Four<L>(pub(crate) L);

impl<L: Lanes4> Arith for Four<L> {
    type N = L::V;

    #[inline(always)]
    fn splat(self, x: f64) -> Self::N {
        self.0.splat(x)
    }
    #[inline(always)]
    fn add(self, a: Self::N, b: Self::N) -> Self::N {
        a + b
    }
    #[inline(always)]
    fn sub(self, a: Self::N, b: Self::N) -> Self::N {
        a - b
    }
    #[inline(always)]
    fn mul(self, a: Self::N, b: Self::N) -> Self::N {
        a * b
    }
    #[inline(always)]
    fn div(self, a: Self::N, b: Self::N) -> Self::N {
        a / b
    }
    #[inline(always)]
    fn sqrt(self, a: Self::N) -> Self::N {
        self.0.sqrt(a)
    }
    #[inline(always)]
    fn abs(self, a: Self::N) -> Self::N {
        self.0.abs(a)
    }
    #[inline(always)]
    fn neg(self, a: Self::N) -> Self::N {
        // As `Eight`'s.
        self.sub(self.splat(-0.0), a)
    }
    #[inline(always)]
    fn pick_gt(self, a: Self::N, b: Self::N, x: Self::N, y: Self::N) -> Self::N {
        self.0.pick_gt(a, b, x, y)
    }
    #[inline(always)]
    fn ge(self, a: Self::N, b: Self::N) -> u32 {
        self.0.ge(a, b)
    }
    #[inline(always)]
    fn gt(self, a: Self::N, b: Self::N) -> u32 {
        self.0.gt(a, b)
    }
    #[inline(always)]
    fn ne(self, a: Self::N, b: Self::N) -> u32 {
        self.0.ne(a, b)
    }
}
