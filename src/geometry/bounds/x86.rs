//! A packet's box test in wider lanes: both children of a node for four rays in one
//! pass of eight AVX2 lanes ([`SlabRay8`]), where [`SlabRay4`] takes two passes of
//! four, and for eight rays in one pass of sixteen AVX-512 lanes ([`SlabRay16`]); a
//! lone ray against a wide node's eight boxes in one pass ([`WideRay8`]); and four
//! f64 lanes in one AVX register ([`Lanes4`] of [`Avx2`]). Each is chosen at run
//! time, on processors that have it, so that the release binary stays portable; the
//! operations are [`SlabRay4::enter`]'s (or one number's), lane for lane, so the
//! results are the same bits.

use std::arch::x86_64::*;

use wide::f32x4;

use super::{
    BoxPair32, DIR_LARGEST, DIR_SMALLEST, GROW, PairTest, PairTest8, SHRINK, SINGLE_LIMIT,
    SlabRay4, WideTest,
};
use crate::geometry::Ray;
use crate::geometry::arith::Lanes4;
use crate::geometry::ray::Rays8;
use wide::f32x8;

/// A proof type that the processor has the instruction sets `$feature`, its `detect`,
/// and its `run`, which calls a closure inlined into a function compiled for them
/// (`$inside`, with `#[target_feature(enable = $enable)]`, the same sets: the
/// attribute takes one literal, the detection one set at a time).
macro_rules! instruction_sets {
    ($(#[$doc:meta])* $name:ident, $inside:ident, [$($feature:tt),+], $enable:literal) => {
        $(#[$doc])*
        #[derive(Debug, Clone, Copy)]
        pub struct $name(());

        impl $name {
            /// `Some` where this processor has these instruction sets.
            #[inline]
            pub fn detect() -> Option<$name> {
                ($(is_x86_feature_detected!($feature))&&+).then_some($name(()))
            }

            /// Runs `f` inlined into a function compiled for these instruction sets, so
            /// that the box tests it makes through them (and all else it inlines) are
            /// compiled for them.
            #[inline(always)]
            pub fn run<R>(self, f: impl FnOnce() -> R) -> R {
                // SAFETY: a proof exists only where the processor has them (`detect`).
                unsafe { $inside(f) }
            }
        }

        /// `f()`, compiled for these instruction sets where it is inlined here.
        #[target_feature(enable = $enable)]
        fn $inside<R>(f: impl FnOnce() -> R) -> R {
            f()
        }
    };
}

instruction_sets!(
    /// Proof that this processor has AVX2, and the way into code compiled for it.
    Avx2,
    in_avx2,
    ["avx2"],
    "avx2"
);

impl Avx2 {
    /// `rays` in eight lanes (inside [`Avx2::run`], where it compiles to a few
    /// permutations).
    #[inline(always)]
    pub fn widen(self, rays: &SlabRay4) -> SlabRay8 {
        // SAFETY: an `Avx2` exists only where the processor has AVX2 (`detect`).
        unsafe { widen(rays) }
    }
}

impl Avx2 {
    /// A lone ray in eight lanes, to test a wide node's eight boxes in one pass: the
    /// numbers [`SlabRay4::splat`] gives it, lane for lane, or `None` where it refuses
    /// the ray. Made in AVX2 lanes, the three axes at once (inside [`Avx2::run`]).
    #[inline(always)]
    pub fn wide_ray(self, ray: &Ray) -> Option<WideRay8> {
        // SAFETY: an `Avx2` exists only where the processor has AVX2 (`detect`).
        unsafe { wide_ray(ray) }
    }
}

/// [`Avx2::wide_ray`]: the origin rounded down and up to `f32` as `round_down` and
/// `round_up` round it, the direction to `f32` and its reciprocal, an axis a lane (the
/// fourth lane's numbers pass every check and are not used). The ray is made as
/// [`wide_rays`] makes eight, in both halves: the compiler does each operation on the
/// two same halves once, so this costs what a four-lane copy of that code did.
#[inline]
#[target_feature(enable = "avx2")]
fn wide_ray(ray: &Ray) -> Option<WideRay8> {
    let (o, d) = (ray.origin, ray.dir);
    let o = _mm256_setr_pd(o.x, o.y, o.z, 0.0);
    let d = _mm256_setr_pd(d.x, d.y, d.z, 1.0);
    let (d, fits) = single_dir([d, d]);
    let (down, up, near) = single_origin([o, o]);
    if fits & near != 0xff {
        return None;
    }
    let inv = _mm256_div_ps(_mm256_set1_ps(1.0), d);
    let lanes = |v: __m256| [0, 1, 2].map(|a| _mm256_permutevar8x32_ps(v, _mm256_set1_epi32(a)));
    Some(WideRay8 {
        o_down: lanes(down),
        o_up: lanes(up),
        inv: lanes(inv),
    })
}

/// Eight direction coordinates (two vectors of four) in `f32`, and the bit set of the
/// lanes whose magnitude the single-precision test takes (ordered comparisons, so
/// that a NaN fails): the one home of that check.
#[inline]
#[target_feature(enable = "avx2")]
fn single_dir(d: [__m256d; 2]) -> (__m256, i32) {
    let d = _mm256_set_m128(_mm256_cvtpd_ps(d[1]), _mm256_cvtpd_ps(d[0]));
    let m = _mm256_andnot_ps(_mm256_set1_ps(-0.0), d);
    let fits = _mm256_and_ps(
        _mm256_cmp_ps::<_CMP_GE_OQ>(m, _mm256_set1_ps(DIR_SMALLEST)),
        _mm256_cmp_ps::<_CMP_LE_OQ>(m, _mm256_set1_ps(DIR_LARGEST)),
    );
    (d, _mm256_movemask_ps(fits))
}

/// Eight origin coordinates (two vectors of four) rounded down and up to `f32` (as
/// `round_down` and `round_up` round them), and the bit set of the lanes within the
/// single-precision test's limit: the one home of that rounding.
#[inline]
#[target_feature(enable = "avx2")]
fn single_origin(o: [__m256d; 2]) -> (__m256, __m256, i32) {
    let near = o.map(|o| {
        _mm256_movemask_pd(_mm256_cmp_pd::<_CMP_LE_OQ>(
            _mm256_andnot_pd(_mm256_set1_pd(-0.0), o),
            _mm256_set1_pd(SINGLE_LIMIT),
        ))
    });
    // Rounded to nearest, then a step toward −∞ (down) or +∞ (up) where that went
    // past the coordinate: the step is −1 on a positive number's bits, +1 on a
    // negative one's (a zero takes the coordinate's sign, so it steps the right way).
    let y = o.map(|o| _mm256_cvtpd_ps(o));
    let back = y.map(|y| _mm256_cvtps_pd(y));
    // A comparison's eight 64-bit answers as eight 32-bit ones, each half's in order.
    let low_words = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
    let words = |m: [__m256d; 2]| {
        let w = m.map(|m| {
            _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(
                _mm256_castpd_si256(m),
                low_words,
            ))
        });
        _mm256_set_m128i(w[1], w[0])
    };
    let above = words([0, 1].map(|h| _mm256_cmp_pd::<_CMP_GT_OQ>(back[h], o[h])));
    let below = words([0, 1].map(|h| _mm256_cmp_pd::<_CMP_LT_OQ>(back[h], o[h])));
    let bits = _mm256_castps_si256(_mm256_set_m128(y[1], y[0]));
    let step = _mm256_or_si256(_mm256_srai_epi32::<31>(bits), _mm256_set1_epi32(1));
    let down = _mm256_castsi256_ps(_mm256_sub_epi32(bits, _mm256_and_si256(above, step)));
    let up = _mm256_castsi256_ps(_mm256_add_epi32(bits, _mm256_and_si256(below, step)));
    (down, up, near[0] | near[1] << 4)
}

impl Avx2 {
    /// Eight rays' lanes for the wide tree, made together (inside [`Avx2::run`]): each
    /// coordinate of the eight rays in one vector, so that the checks, the rounding and
    /// the reciprocals take a few instructions for all eight where [`Avx2::wide_ray`]
    /// takes them for one. [`WideRays8::lane`] gives each ray's, bit for bit what
    /// `wide_ray` gives it.
    #[inline(always)]
    pub fn wide_rays(self, rays: &Rays8) -> WideRays8 {
        // SAFETY: an `Avx2` exists only where the processor has AVX2 (`detect`).
        unsafe { wide_rays(rays) }
    }
}

/// [`Avx2::wide_rays`]: [`wide_ray`]'s operations, a ray a lane.
#[inline]
#[target_feature(enable = "avx2")]
fn wide_rays(rays: &Rays8) -> WideRays8 {
    let halves = |v: &[f64; 8]| {
        let (lo, hi) = v.split_at(4);
        // SAFETY: four `f64` each, read unaligned.
        unsafe { [_mm256_loadu_pd(lo.as_ptr()), _mm256_loadu_pd(hi.as_ptr())] }
    };
    let mut fits = 0xff;
    let mut lanes = WideRays8 {
        fits: 0,
        o_down: [_mm256_setzero_ps(); 3],
        o_up: [_mm256_setzero_ps(); 3],
        inv: [_mm256_setzero_ps(); 3],
    };
    for a in 0..3 {
        let (d, d_fits) = single_dir(halves(&rays.dir[a]));
        let (down, up, near) = single_origin(halves(&rays.origin[a]));
        fits &= d_fits & near;
        lanes.inv[a] = _mm256_div_ps(_mm256_set1_ps(1.0), d);
        (lanes.o_down[a], lanes.o_up[a]) = (down, up);
    }
    lanes.fits = fits as u32;
    lanes
}

/// Eight rays in AVX2 lanes, a ray a lane ([`Avx2::wide_rays`]), each to be tested
/// alone against the wide tree ([`WideRays8::lane`]).
#[derive(Debug, Clone, Copy)]
pub struct WideRays8 {
    /// The lanes whose rays' numbers fit the single-precision test.
    fits: u32,
    o_down: [__m256; 3],
    o_up: [__m256; 3],
    inv: [__m256; 3],
}

impl WideRays8 {
    /// Ray `k`'s lanes for a wide node's test, [`Avx2::wide_ray`]'s numbers bit for
    /// bit, or `None` where they do not fit (or `k` is not a lane).
    #[inline(always)]
    pub fn lane(&self, k: usize) -> Option<WideRay8> {
        (k < 8 && self.fits >> k & 1 == 1).then(|| {
            // SAFETY: a `WideRays8` exists only where the processor has AVX2 (`Avx2`).
            unsafe { self.lane_avx2(k as i32) }
        })
    }

    /// [`WideRays8::lane`] of a lane that fits, in AVX2.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn lane_avx2(&self, k: i32) -> WideRay8 {
        let k = _mm256_set1_epi32(k);
        let every = |v: &[__m256; 3]| v.map(|v| _mm256_permutevar8x32_ps(v, k));
        WideRay8 {
            o_down: every(&self.o_down),
            o_up: every(&self.o_up),
            inv: every(&self.inv),
        }
    }
}

/// One ray in eight AVX2 lanes, against a wide node's eight boxes. Made only by
/// [`Avx2::wide_ray`], so only where the processor has AVX2.
#[derive(Debug, Clone, Copy)]
pub struct WideRay8 {
    o_down: [__m256; 3],
    o_up: [__m256; 3],
    inv: [__m256; 3],
}

impl WideRay8 {
    /// [`WideTest::enter_wide`], in AVX2.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn enter_wide_avx2(&self, planes: &[[f32; 8]; 6], t_min: f32, t_max: f32) -> u32 {
        let mut near = _mm256_set1_ps(t_min);
        let mut far = _mm256_set1_ps(t_max);
        for a in 0..3 {
            // SAFETY: each row is eight `f32`, read unaligned.
            let (lo, hi) = unsafe {
                (
                    _mm256_loadu_ps(planes[a].as_ptr()),
                    _mm256_loadu_ps(planes[a + 3].as_ptr()),
                )
            };
            let t0 = _mm256_mul_ps(_mm256_sub_ps(lo, self.o_up[a]), self.inv[a]);
            let t1 = _mm256_mul_ps(_mm256_sub_ps(hi, self.o_down[a]), self.inv[a]);
            near = _mm256_max_ps(near, _mm256_min_ps(t0, t1));
            far = _mm256_min_ps(far, _mm256_max_ps(t0, t1));
        }
        let near = _mm256_mul_ps(near, _mm256_set1_ps(SHRINK));
        let hit = _mm256_cmp_ps::<_CMP_LE_OS>(near, _mm256_mul_ps(far, _mm256_set1_ps(GROW)));
        _mm256_movemask_ps(hit) as u32
    }
}

impl WideTest for WideRay8 {
    #[inline(always)]
    fn enter_wide(&self, planes: &[[f32; 8]; 6], t_min: f32, t_max: f32) -> u32 {
        // SAFETY: a `WideRay8` exists only where the processor has AVX2 (`Avx2`).
        unsafe { self.enter_wide_avx2(planes, t_min, t_max) }
    }
}

/// A packet's [`SlabRay4`] numbers in wider vectors `V`, each ray twice: lane `2r + c`
/// is ray `r` against child `c`, so that one 64-bit load of a [`BoxPair32`]
/// coordinate, broadcast, lines up with it.
#[derive(Debug, Clone, Copy)]
pub struct WideSlab<V> {
    o_down: [V; 3],
    o_up: [V; 3],
    inv: [V; 3],
}

/// A [`SlabRay4`] in eight AVX2 lanes. Made only by [`Avx2::widen`], so only where the
/// processor has AVX2.
pub type SlabRay8 = WideSlab<__m256>;

impl SlabRay8 {
    /// [`PairTest::enter_pair`], in AVX2.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn enter_pair_avx2(&self, b: &BoxPair32, t_min: f32, t_max: f32x4) -> [(u32, f32x4); 2] {
        let mut near = _mm256_set1_ps(t_min);
        let mut far = twice(bytemuck::cast(t_max));
        for a in 0..3 {
            let t0 = _mm256_mul_ps(_mm256_sub_ps(pair(&b.min[a]), self.o_up[a]), self.inv[a]);
            let t1 = _mm256_mul_ps(_mm256_sub_ps(pair(&b.max[a]), self.o_down[a]), self.inv[a]);
            near = _mm256_max_ps(near, _mm256_min_ps(t0, t1));
            far = _mm256_min_ps(far, _mm256_max_ps(t0, t1));
        }
        let near = _mm256_mul_ps(near, _mm256_set1_ps(SHRINK));
        let hit = _mm256_cmp_ps::<_CMP_LE_OS>(near, _mm256_mul_ps(far, _mm256_set1_ps(GROW)));
        // The children apart: lanes 0–3 child 0's rays, 4–7 child 1's.
        let apart = _mm256_setr_epi32(0, 2, 4, 6, 1, 3, 5, 7);
        let bits = _mm256_movemask_ps(_mm256_permutevar8x32_ps(hit, apart)) as u32;
        let near = _mm256_permutevar8x32_ps(near, apart);
        [
            (bits & 0b1111, bytemuck::cast(_mm256_castps256_ps128(near))),
            (bits >> 4, bytemuck::cast(_mm256_extractf128_ps::<1>(near))),
        ]
    }
}

impl PairTest for SlabRay8 {
    #[inline(always)]
    fn enter_pair(&self, b: &BoxPair32, t_min: f32, t_max: f32x4) -> [(u32, f32x4); 2] {
        // SAFETY: a `SlabRay8` exists only where the processor has AVX2 (`Avx2`).
        unsafe { self.enter_pair_avx2(b, t_min, t_max) }
    }
}

/// Four f64 lanes in one AVX register. Made only by [`Avx2`]'s [`Lanes4`], so only
/// where the processor has AVX2: each operation is one instruction of it.
#[derive(Debug, Clone, Copy)]
pub struct F64x4Avx(__m256d);

/// An operator of [`F64x4Avx`] as its one AVX instruction.
macro_rules! avx_operator {
    ($trait:ident, $method:ident, $intrinsic:ident) => {
        impl std::ops::$trait for F64x4Avx {
            type Output = F64x4Avx;

            #[inline(always)]
            fn $method(self, rhs: F64x4Avx) -> F64x4Avx {
                // SAFETY: an `F64x4Avx` exists only where the processor has AVX2.
                F64x4Avx(unsafe { $intrinsic(self.0, rhs.0) })
            }
        }
    };
}

avx_operator!(Add, add, _mm256_add_pd);
avx_operator!(Sub, sub, _mm256_sub_pd);
avx_operator!(Mul, mul, _mm256_mul_pd);
avx_operator!(Div, div, _mm256_div_pd);

/// The bit set of the lanes where comparison `P` of `a` and `b` holds.
#[inline(always)]
fn compared<const P: i32>(a: F64x4Avx, b: F64x4Avx) -> u32 {
    // SAFETY: an `F64x4Avx` exists only where the processor has AVX2.
    unsafe { _mm256_movemask_pd(_mm256_cmp_pd::<P>(a.0, b.0)) as u32 }
}

impl Lanes4 for Avx2 {
    type V = F64x4Avx;

    #[inline(always)]
    fn splat(self, x: f64) -> F64x4Avx {
        // SAFETY: an `Avx2` exists only where the processor has AVX2 (`detect`).
        F64x4Avx(unsafe { _mm256_set1_pd(x) })
    }

    #[inline(always)]
    fn load(self, x: &[f64; 4]) -> F64x4Avx {
        F64x4Avx(bytemuck::cast(*x))
    }

    #[inline(always)]
    fn store(self, v: F64x4Avx) -> [f64; 4] {
        bytemuck::cast(v.0)
    }

    #[inline(always)]
    fn ge(self, a: F64x4Avx, b: F64x4Avx) -> u32 {
        compared::<_CMP_GE_OQ>(a, b)
    }

    #[inline(always)]
    fn gt(self, a: F64x4Avx, b: F64x4Avx) -> u32 {
        compared::<_CMP_GT_OQ>(a, b)
    }

    #[inline(always)]
    fn le(self, a: F64x4Avx, b: F64x4Avx) -> u32 {
        compared::<_CMP_LE_OQ>(a, b)
    }

    #[inline(always)]
    fn ne(self, a: F64x4Avx, b: F64x4Avx) -> u32 {
        compared::<_CMP_NEQ_UQ>(a, b)
    }

    #[inline(always)]
    fn sqrt(self, a: F64x4Avx) -> F64x4Avx {
        // SAFETY: an `Avx2` exists only where the processor has AVX2 (`detect`).
        F64x4Avx(unsafe { _mm256_sqrt_pd(a.0) })
    }

    #[inline(always)]
    fn abs(self, a: F64x4Avx) -> F64x4Avx {
        // SAFETY: as above.
        F64x4Avx(unsafe { _mm256_andnot_pd(_mm256_set1_pd(-0.0), a.0) })
    }

    #[inline(always)]
    fn pick_gt(self, a: F64x4Avx, b: F64x4Avx, x: F64x4Avx, y: F64x4Avx) -> F64x4Avx {
        // SAFETY: as above.
        F64x4Avx(unsafe { _mm256_blendv_pd(y.0, x.0, _mm256_cmp_pd::<_CMP_GT_OQ>(a.0, b.0)) })
    }
}

instruction_sets!(
    /// Proof that this processor has AVX-512 (its foundation) and AVX2, and the way
    /// into code compiled for them.
    Avx512,
    in_avx512,
    ["avx512f", "avx2"],
    "avx512f,avx2"
);

impl Avx512 {
    /// Eight rays, as two packets of four, in sixteen lanes.
    #[inline(always)]
    pub fn widen(self, rays: &[SlabRay4; 2]) -> SlabRay16 {
        // SAFETY: an `Avx512` exists only where the processor has it (`detect`).
        unsafe { widen16(rays) }
    }
}

/// Eight rays (two [`SlabRay4`]s) in sixteen AVX-512 lanes. Made only by
/// [`Avx512::widen`], so only where the processor has AVX-512.
pub type SlabRay16 = WideSlab<__m512>;

/// Lane `2r + c` ← lane `r`: each of eight lanes twice.
#[inline]
#[target_feature(enable = "avx512f,avx2")]
fn twice16(x: __m256) -> __m512 {
    _mm512_permutexvar_ps(
        _mm512_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3, 4, 4, 5, 5, 6, 6, 7, 7),
        _mm512_castps256_ps512(x),
    )
}

#[inline]
#[target_feature(enable = "avx512f,avx2")]
fn widen16(rays: &[SlabRay4; 2]) -> SlabRay16 {
    let each = |f: fn(&SlabRay4) -> &[f32x4; 3]| {
        [0, 1, 2].map(|a| {
            let (lo, hi) = (f(&rays[0])[a], f(&rays[1])[a]);
            twice16(_mm256_set_m128(bytemuck::cast(hi), bytemuck::cast(lo)))
        })
    };
    SlabRay16 {
        o_down: each(|r| &r.o_down),
        o_up: each(|r| &r.o_up),
        inv: each(|r| &r.inv),
    }
}

impl SlabRay16 {
    /// [`PairTest8::enter_pair8`], in AVX-512.
    #[inline]
    #[target_feature(enable = "avx512f,avx2")]
    fn enter_pair16(&self, b: &BoxPair32, t_min: f32, t_max: f32x8) -> [(u32, f32x8); 2] {
        let mut near = _mm512_set1_ps(t_min);
        let mut far = twice16(bytemuck::cast(t_max));
        for a in 0..3 {
            let t0 = _mm512_mul_ps(_mm512_sub_ps(pair16(&b.min[a]), self.o_up[a]), self.inv[a]);
            let t1 = _mm512_mul_ps(
                _mm512_sub_ps(pair16(&b.max[a]), self.o_down[a]),
                self.inv[a],
            );
            near = _mm512_max_ps(near, _mm512_min_ps(t0, t1));
            far = _mm512_min_ps(far, _mm512_max_ps(t0, t1));
        }
        // The children apart (lanes 0–7 child 0's rays, 8–15 child 1's), then compared.
        let apart = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 1, 3, 5, 7, 9, 11, 13, 15);
        let near = _mm512_permutexvar_ps(apart, _mm512_mul_ps(near, _mm512_set1_ps(SHRINK)));
        let far = _mm512_permutexvar_ps(apart, _mm512_mul_ps(far, _mm512_set1_ps(GROW)));
        let bits = u32::from(_mm512_cmp_ps_mask::<_CMP_LE_OS>(near, far));
        let upper = _mm512_castpd_ps(_mm512_castpd256_pd512(_mm512_extractf64x4_pd::<1>(
            _mm512_castps_pd(near),
        )));
        [
            (bits & 0xff, bytemuck::cast(_mm512_castps512_ps256(near))),
            (bits >> 8, bytemuck::cast(_mm512_castps512_ps256(upper))),
        ]
    }
}

impl PairTest8 for SlabRay16 {
    #[inline(always)]
    fn enter_pair8(&self, b: &BoxPair32, t_min: f32, t_max: f32x8) -> [(u32, f32x8); 2] {
        // SAFETY: a `SlabRay16` exists only where the processor has AVX-512 (`Avx512`).
        unsafe { self.enter_pair16(b, t_min, t_max) }
    }
}

/// A coordinate of both children in sixteen lanes, `[b₀ b₁ b₀ b₁ …]`: one load.
#[inline]
#[target_feature(enable = "avx512f,avx2")]
fn pair16(p: &[f32; 2]) -> __m512 {
    _mm512_castpd_ps(_mm512_set1_pd(f64::from_bits(bytemuck::cast(*p))))
}

/// `rays`' lanes, each twice.
#[inline]
#[target_feature(enable = "avx2")]
fn widen(rays: &SlabRay4) -> SlabRay8 {
    let each = |x: [f32x4; 3]| x.map(|v| twice(bytemuck::cast(v)));
    SlabRay8 {
        o_down: each(rays.o_down),
        o_up: each(rays.o_up),
        inv: each(rays.inv),
    }
}

/// `[x₀ x₀ x₁ x₁ x₂ x₂ x₃ x₃]`.
#[inline]
#[target_feature(enable = "avx2")]
fn twice(x: __m128) -> __m256 {
    _mm256_permutevar8x32_ps(
        _mm256_castps128_ps256(x),
        _mm256_setr_epi32(0, 0, 1, 1, 2, 2, 3, 3),
    )
}

/// A coordinate of both children, `[b₀ b₁ b₀ b₁ b₀ b₁ b₀ b₁]`: one load.
#[inline]
#[target_feature(enable = "avx2")]
fn pair(p: &[f32; 2]) -> __m256 {
    _mm256_castpd_ps(_mm256_set1_pd(f64::from_bits(bytemuck::cast(*p))))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Ray;
    use crate::geometry::bounds::{Aabb, SlabRay, lanes, lanes8};
    use glam::DVec3;
    use proptest::prelude::*;

    /// Coordinates on a coarse grid, so that rays graze faces, edges and corners.
    fn coord() -> impl Strategy<Value = f64> {
        prop_oneof![(-8i32..8).prop_map(|c| c as f64 * 0.5), -4.0f64..4.0]
    }

    fn aabb() -> impl Strategy<Value = Aabb> {
        (
            prop::array::uniform3(coord()),
            prop::array::uniform3(0.0f64..3.0),
        )
            .prop_map(|(lo, size)| Aabb {
                min: DVec3::from(lo),
                max: DVec3::from(lo) + DVec3::from(size),
            })
    }

    /// A wide node's rows for `boxes`, each rounded outward as the tree rounds it:
    /// `planes[k][c]` is coordinate `k` of box `c` in [`Box32`]'s order.
    fn wide_planes(boxes: &[Aabb; 8]) -> [[f32; 8]; 6] {
        let mut planes = [[0f32; 8]; 6];
        for (c, b) in boxes.iter().enumerate() {
            for (k, x) in super::super::box32(b).into_iter().enumerate() {
                planes[k][c] = x;
            }
        }
        planes
    }

    fn dir() -> impl Strategy<Value = f64> {
        prop_oneof![
            Just(1.0),
            Just(-1.0),
            Just(0.5),
            -1.0f64..-1e-3,
            1e-3f64..1.0
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        #[test]
        fn sixteen_lanes_give_what_four_lanes_give_bit_for_bit(
            a in aabb(),
            b in aabb(),
            origins in prop::array::uniform8(prop::array::uniform3(coord())),
            shared in any::<bool>(),
            dirs in prop::array::uniform8(prop::array::uniform3(dir())),
            t_max in prop::array::uniform8(prop_oneof![Just(f64::INFINITY), 0.0f64..12.0]),
            t_min in prop_oneof![Just(0.0), 0.0f64..2.0],
        ) {
            let rays: [Ray; 8] = std::array::from_fn(|k| {
                let o = if shared { origins[0] } else { origins[k] };
                Ray::new(DVec3::from(o), DVec3::from(dirs[k]))
            });
            let four = SlabRay4::pair(&rays).expect("no zero direction component");
            let Some(avx512) = Avx512::detect() else {
                // Nothing to compare on a processor without AVX-512.
                return Ok(());
            };
            let pair = BoxPair32::new(&a, &b);
            let wide = avx512.widen(&four).enter_pair8(&pair, t_min as f32, lanes8(&t_max));
            let narrow = four.enter_pair8(&pair, t_min as f32, lanes8(&t_max));
            for c in 0..2 {
                prop_assert_eq!(wide[c].0, narrow[c].0, "child {}", c);
                prop_assert_eq!(
                    wide[c].1.to_array().map(f32::to_bits),
                    narrow[c].1.to_array().map(f32::to_bits),
                    "child {}", c
                );
            }
            // And each half is `enter_pair`'s for its four rays.
            let (t_lo, t_hi) = super::super::halves(&t_max);
            for (h, t) in [t_lo, t_hi].into_iter().enumerate() {
                let half = four[h].enter_pair(&pair, t_min as f32, lanes(t));
                for c in 0..2 {
                    prop_assert_eq!((narrow[c].0 >> (4 * h)) & 0b1111, half[c].0);
                    prop_assert_eq!(
                        &narrow[c].1.to_array()[4 * h..4 * h + 4],
                        &half[c].1.to_array()[..]
                    );
                }
            }
        }

        #[test]
        fn a_wide_nodes_eight_boxes_in_one_pass_give_what_two_passes_give(
            boxes in prop::array::uniform8(aabb()),
            origin in prop::array::uniform3(coord()),
            d in prop::array::uniform3(dir()),
            t_max in prop_oneof![Just(f64::INFINITY), 0.0f64..12.0],
            t_min in prop_oneof![Just(0.0), 0.0f64..2.0],
        ) {
            let ray = Ray::new(DVec3::from(origin), DVec3::from(d));
            let four = SlabRay4::splat(&ray).expect("no zero direction component");
            let Some(avx2) = Avx2::detect() else {
                // Nothing to compare on a processor without AVX2.
                return Ok(());
            };
            let wide = avx2.wide_ray(&ray).expect("no zero direction component");
            let planes = wide_planes(&boxes);
            let (t_min, t_max) = (t_min as f32, t_max as f32);
            let one = wide.enter_wide(&planes, t_min, t_max);
            prop_assert_eq!(one, four.enter_wide(&planes, t_min, t_max));
            // And each box's bit is `enter`'s of that box alone.
            for (c, b) in boxes.iter().enumerate() {
                let (hit, _) = four.enter(
                    &super::super::box32(b),
                    f32x4::splat(t_min),
                    f32x4::splat(t_max),
                );
                prop_assert_eq!(one >> c & 1, hit & 1, "box {}", c);
            }
        }

        #[test]
        fn eight_lanes_give_what_four_lanes_give_bit_for_bit(
            a in aabb(),
            b in aabb(),
            origins in prop::array::uniform4(prop::array::uniform3(coord())),
            shared in any::<bool>(),
            dirs in prop::array::uniform4(prop::array::uniform3(dir())),
            t_max in prop::array::uniform4(prop_oneof![Just(f64::INFINITY), 0.0f64..12.0]),
            t_min in prop_oneof![Just(0.0), 0.0f64..2.0],
        ) {
            let rays: [Ray; 4] = [0, 1, 2, 3].map(|k| {
                let o = if shared { origins[0] } else { origins[k] };
                Ray::new(DVec3::from(o), DVec3::from(dirs[k]))
            });
            let four = SlabRay4::new(&rays).expect("no zero direction component");
            let Some(avx2) = Avx2::detect() else {
                // Nothing to compare on a processor without AVX2.
                return Ok(());
            };
            let eight = avx2.widen(&four);
            let pair = BoxPair32::new(&a, &b);
            let wide = eight.enter_pair(&pair, t_min as f32, lanes(&t_max));
            let narrow = four.enter_pair(&pair, t_min as f32, lanes(&t_max));
            for c in 0..2 {
                prop_assert_eq!(wide[c].0, narrow[c].0, "child {}", c);
                prop_assert_eq!(
                    wide[c].1.to_array().map(f32::to_bits),
                    narrow[c].1.to_array().map(f32::to_bits),
                    "child {}", c
                );
            }
            // And the four lanes are `enter`'s, child by child.
            for (c, boxed) in [a, b].iter().enumerate() {
                let (hit, near) = four.enter(
                    &super::super::box32(boxed),
                    f32x4::splat(t_min as f32),
                    lanes(&t_max),
                );
                prop_assert_eq!(hit, narrow[c].0);
                prop_assert_eq!(near.to_array(), narrow[c].1.to_array());
            }
        }
    }

    /// A ray from an origin that `f32` cannot hold, within a rounding of one of box
    /// `b`'s faces (just outside it or just inside), crossing it: the face at `axis`,
    /// its lower one where `lower`, the origin `gap` from it (negative: inside), the
    /// other coordinates at `at` of the way across the box, and limits `t_min` and
    /// `t_max` about the crossing `λ` (scaled by `scale`), so that whether the box
    /// is entered turns on where in its rounding the origin is taken.
    fn near_face(
        b: &Aabb,
        axis: usize,
        lower: bool,
        gap: f64,
        at: [f64; 2],
        d: [f64; 3],
        scale: [f64; 2],
    ) -> (Ray, f64, f64) {
        let (lo, hi) = (b.min.to_array(), b.max.to_array());
        let mut o = [0.0; 3];
        o[axis] = if lower {
            lo[axis] - gap
        } else {
            hi[axis] + gap
        };
        for (u, k) in at.into_iter().zip([(axis + 1) % 3, (axis + 2) % 3]) {
            o[k] = lo[k] + u * (hi[k] - lo[k]);
        }
        // Toward the face from outside, away from it from inside: the ray crosses it.
        let mut d = d;
        let inward = if lower { 1.0 } else { -1.0 };
        d[axis] = d[axis].abs() * if gap > 0.0 { inward } else { -inward };
        let crossing = gap.abs() / d[axis].abs();
        let t_min = if gap > 0.0 { 0.0 } else { crossing * scale[0] };
        (
            Ray::new(DVec3::from(o), DVec3::from(d)),
            t_min,
            crossing * scale[1],
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// Rays from origins within a rounding of a box's face: the eight lanes (and
        /// the two passes of four) never reject a box that the double-precision test
        /// enters. The origin is taken rounded down or up by plane and direction, so
        /// that the single-precision distances bound the exact ones; one rounded the
        /// other way turns such a ray away.
        #[test]
        fn a_wide_node_keeps_boxes_entered_from_origins_f32_cannot_hold(
            boxes in prop::array::uniform8(
                (prop::array::uniform3(coord()), prop::array::uniform3(0.5f64..3.0))
                    .prop_map(|(lo, size)| Aabb {
                        min: DVec3::from(lo),
                        max: DVec3::from(lo) + DVec3::from(size),
                    })
            ),
            which in 0usize..8,
            axis in 0usize..3,
            lower in any::<bool>(),
            gap in prop_oneof![1e-12f64..1e-8, -1e-8f64..-1e-12],
            at in prop::array::uniform2(0.05f64..0.95),
            d in prop::array::uniform3(dir()),
            scale in (0.0f64..0.9, prop_oneof![1.5f64..4.0, 4.0f64..1e3]),
        ) {
            let (ray, t_min, t_max) =
                near_face(&boxes[which], axis, lower, gap, at, d, [scale.0, scale.1]);
            let exact = SlabRay::new(ray.origin, ray.dir);
            let four = SlabRay4::splat(&ray).expect("no zero direction component");
            let planes = wide_planes(&boxes);
            let (t_min32, t_max32) = (t_min as f32, t_max as f32);
            let two = four.enter_wide(&planes, t_min32, t_max32);
            let one = Avx2::detect().map(|avx2| {
                let wide = avx2.wide_ray(&ray).expect("no zero direction component");
                wide.enter_wide(&planes, t_min32, t_max32)
            });
            prop_assert!(
                exact.enter(boxes[which].min, boxes[which].max, t_min, t_max).is_some(),
                "the ray crosses box {}'s face within its limits", which
            );
            for (c, b) in boxes.iter().enumerate() {
                if exact.enter(b.min, b.max, t_min, t_max).is_some() {
                    prop_assert_eq!(two >> c & 1, 1, "two passes, box {}", c);
                    if let Some(one) = one {
                        prop_assert_eq!(one >> c & 1, 1, "one pass, box {}", c);
                    }
                }
            }
        }
    }

    /// Numbers of every kind a coordinate can hold: ordinary ones, those `f32` holds
    /// exactly and those it does not, zeros of either sign, subnormal and huge ones,
    /// the single-precision test's limits and about them, infinities and NaN.
    fn any_number() -> impl Strategy<Value = f64> {
        prop_oneof![
            20 => -8.0f64..8.0,
            10 => (-64i32..64).prop_map(|c| c as f64 * 0.125),
            1 => Just(0.0),
            1 => Just(-0.0),
            1 => prop_oneof![-1e-35f64..1e-35, -1e-39f64..1e-39, -1e-300f64..1e-300, Just(5e-324)],
            1 => prop_oneof![Just(1e30), Just(-1e30), Just(1.000_000_1e30), -1e40f64..1e40],
            // About the limits of a direction's magnitude, 10⁻³⁰ and 10³⁰ in `f32`.
            1 => prop_oneof![1e-31f64..1e-29, -1e-29f64..-1e-31, 1e29f64..1e31, -1e31f64..-1e29],
            1 => prop_oneof![Just(f64::INFINITY), Just(f64::NEG_INFINITY), Just(f64::NAN)],
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2048))]

        /// A lone ray made in AVX2 lanes holds [`SlabRay4::splat`]'s numbers in every
        /// lane, bit for bit, and is refused where that refuses it.
        #[test]
        fn a_wide_ray_is_the_splat_rays_numbers_in_every_lane(
            origin in prop::array::uniform3(any_number()),
            dir in prop::array::uniform3(any_number()),
        ) {
            let Some(avx2) = Avx2::detect() else {
                // Nothing to compare on a processor without AVX2.
                return Ok(());
            };
            let ray = Ray::new(DVec3::from(origin), DVec3::from(dir));
            let four = SlabRay4::splat(&ray);
            let wide = avx2.wide_ray(&ray);
            prop_assert_eq!(four.is_some(), wide.is_some());
            let (Some(four), Some(wide)) = (four, wide) else {
                return Ok(());
            };
            let bits8 = |v: &[__m256; 3]| v.map(|v| bytemuck::cast::<__m256, [f32; 8]>(v).map(f32::to_bits));
            let bits4 = |v: &[f32x4; 3]| v.map(|v| [v.to_array(); 2].concat().iter().map(|x| x.to_bits()).collect::<Vec<_>>());
            for (name, w, f) in [
                ("o_down", &wide.o_down, &four.o_down),
                ("o_up", &wide.o_up, &four.o_up),
                ("inv", &wide.inv, &four.inv),
            ] {
                let (w, f) = (bits8(w), bits4(f));
                for a in 0..3 {
                    prop_assert_eq!(&w[a][..], &f[a][..], "{} axis {}", name, a);
                }
            }
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// Eight rays made together hold, lane by lane, what each made alone holds, bit
        /// for bit, and each is refused where alone it is.
        #[test]
        fn eight_rays_made_together_are_each_the_lone_rays_numbers(
            numbers in prop::collection::vec(any_number(), 48),
        ) {
            let Some(avx2) = Avx2::detect() else {
                return Ok(());
            };
            let at = |i: usize| DVec3::new(numbers[i], numbers[i + 1], numbers[i + 2]);
            let rays: [Ray; 8] = std::array::from_fn(|k| Ray::new(at(6 * k), at(6 * k + 3)));
            let eight = avx2.wide_rays(&Rays8::from_rays(&rays));
            let bits = |r: &WideRay8| {
                [r.o_down, r.o_up, r.inv]
                    .map(|v| v.map(|v| bytemuck::cast::<__m256, [f32; 8]>(v).map(f32::to_bits)))
            };
            for (k, ray) in rays.iter().enumerate() {
                let (alone, together) = (avx2.wide_ray(ray), eight.lane(k));
                prop_assert_eq!(alone.is_some(), together.is_some(), "ray {}", k);
                if let (Some(alone), Some(together)) = (alone, together) {
                    prop_assert_eq!(bits(&alone), bits(&together), "ray {}", k);
                }
            }
            prop_assert!(eight.lane(8).is_none());
        }
    }
}
