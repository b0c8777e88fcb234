//! Axis-aligned bounding boxes and the ray-box slab test used by the BVH.

use glam::{DAffine3, DVec3};
use wide::f32x4;

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

/// The boxes of up to four children in single precision, rounded outward from their
/// double-precision bounds (so they only grow, and no ray that enters the exact box
/// misses this one), laid out plane by plane with a lane per child, so one SIMD
/// operation tests all four: `planes[k][child]`, with `k` = 0, 1, 2 the low x, y, z and
/// 3, 4, 5 the high ones. An unused lane holds the empty box (low +∞, high −∞), which no
/// ray enters.
#[derive(Debug, Clone, Copy, PartialEq)]
#[repr(C, align(16))]
pub struct Boxes4 {
    /// `planes[k][child]`.
    pub planes: [[f32; 4]; 6],
}

impl Boxes4 {
    /// Four empty lanes.
    pub const EMPTY: Boxes4 = Boxes4 {
        planes: [
            [f32::INFINITY; 4],
            [f32::INFINITY; 4],
            [f32::INFINITY; 4],
            [f32::NEG_INFINITY; 4],
            [f32::NEG_INFINITY; 4],
            [f32::NEG_INFINITY; 4],
        ],
    };

    /// Puts `b`, rounded outward to single precision, in lane `lane`. A coordinate
    /// beyond ±10³⁰ is pushed outward to that bound or to infinity, so that no slab
    /// distance of the single-precision test overflows in its subtraction.
    pub fn set(&mut self, lane: usize, b: &Aabb) {
        for a in 0..3 {
            let (lo, hi) = (b.min[a], b.max[a]);
            self.planes[a][lane] = if lo < -SINGLE_MAX {
                f32::NEG_INFINITY
            } else {
                round_down(lo.min(SINGLE_MAX))
            };
            self.planes[a + 3][lane] = if hi > SINGLE_MAX {
                f32::INFINITY
            } else {
                round_up(hi.max(-SINGLE_MAX))
            };
        }
    }

    /// The box in lane `lane`, exactly as stored.
    pub fn lane(&self, lane: usize) -> Aabb {
        let p = |k: usize| self.planes[k][lane] as f64;
        Aabb {
            min: DVec3::new(p(0), p(1), p(2)),
            max: DVec3::new(p(3), p(4), p(5)),
        }
    }
}

/// The largest `f32` at most `x`.
pub fn round_down(x: f64) -> f32 {
    let y = x as f32;
    if y as f64 > x { y.next_down() } else { y }
}

/// The smallest `f32` at least `x`.
pub fn round_up(x: f64) -> f32 {
    let y = x as f32;
    if (y as f64) < x { y.next_up() } else { y }
}

/// A ray prepared for many slab tests: its origin and reciprocal direction, and which
/// plane of a box it enters and leaves by on each axis (the low one when it moves up
/// the axis), so the test needs no `min`/`max` per axis.
#[derive(Debug, Clone, Copy)]
pub struct SlabRay {
    origin: DVec3,
    inv_dir: DVec3,
    /// Per axis, the index into [`Boxes4::planes`] of the plane it enters by.
    near: [usize; 3],
    /// Per axis, the plane it leaves by.
    far: [usize; 3],
    /// The single-precision set-up, when the ray's numbers allow a conservative test in
    /// `f32` (see [`SlabRay::new`]); otherwise boxes are tested in `f64`.
    single: Option<Single>,
}

/// A ray's terms for the single-precision slab test. The origin is taken as two
/// `f32`s, one rounded down and one up, and each slab subtracts the one that makes its
/// distance err outward, so that the only error left is relative rounding, which the
/// test's final scaling covers.
#[derive(Debug, Clone, Copy)]
struct Single {
    /// Per axis, the origin bound subtracted from the entry plane (the larger one when
    /// the ray moves up the axis).
    o_near: [f32; 3],
    /// Per axis, the origin bound subtracted from the exit plane.
    o_far: [f32; 3],
    /// `1 / d` rounded to `f32`: ±∞ for a zero component.
    inv: [f32; 3],
}

/// Scales an entry distance down, and an exit distance up, by more than the relative
/// rounding of a single-precision slab distance (three roundings of 2⁻²⁴ each, and
/// one of `t_min` or `t_max` to `f32`), so that the test never rejects a box the ray
/// enters. 2⁻²⁰ leaves a wide margin.
const SHRINK: f32 = 1.0 - 1.0 / (1u32 << 20) as f32;
const GROW: f32 = 1.0 + 1.0 / (1u32 << 20) as f32;

/// Direction components and origin coordinates within these magnitudes (or exactly
/// zero, for a direction) keep every slab distance of the `f32` test a normal number
/// or an exact infinity, so its rounding is purely relative.
const SINGLE_MIN_DIR: f64 = 1e-30;
const SINGLE_MAX: f64 = 1e30;

/// `max(t, acc)`, keeping `acc` where `t` is NaN: `0 · ∞` from a ray running exactly in
/// a slab's plane, which must not constrain the interval. On x86 `maxps` returns its
/// second operand when either is NaN, so this is one instruction; elsewhere `wide`'s
/// NaN-ignoring `max`.
#[inline(always)]
fn max_keep(t: f32x4, acc: f32x4) -> f32x4 {
    #[cfg(target_feature = "sse")]
    {
        t.fast_max(acc)
    }
    #[cfg(not(target_feature = "sse"))]
    {
        acc.max(t)
    }
}

/// `min(t, acc)`, keeping `acc` where `t` is NaN (see [`max_keep`]).
#[inline(always)]
fn min_keep(t: f32x4, acc: f32x4) -> f32x4 {
    #[cfg(target_feature = "sse")]
    {
        t.fast_min(acc)
    }
    #[cfg(not(target_feature = "sse"))]
    {
        acc.min(t)
    }
}

/// `min` and `max` as single instructions: the operands are never NaN here.
#[inline(always)]
fn fmin(a: f64, b: f64) -> f64 {
    if a < b { a } else { b }
}

#[inline(always)]
fn fmax(a: f64, b: f64) -> f64 {
    if a > b { a } else { b }
}

impl SlabRay {
    /// Prepares `origin + λ dir`.
    ///
    /// For the double-precision test a zero direction component is replaced by a tiny
    /// one of the same sign, so the reciprocal is finite and `0 · ∞ = NaN` never
    /// arises. A ray running exactly in a box's face plane then counts as leaving it;
    /// the BVH pads its boxes (see [`Aabb::padded`]), so such a plane never holds a
    /// surface point.
    ///
    /// The single-precision test is used when every origin coordinate is within
    /// ±10³⁰ and every direction component is zero or of magnitude in [10⁻³⁰, 10³⁰]:
    /// always, for a scene of sensible size. Otherwise [`SlabRay::enter4`] tests in
    /// `f64`, with the same result.
    #[inline]
    pub fn new(origin: DVec3, dir: DVec3) -> Self {
        let safe = |d: f64| {
            if d.abs() < 1e-300 {
                1e-300f64.copysign(d)
            } else {
                d
            }
        };
        let neg = [
            dir.x.is_sign_negative(),
            dir.y.is_sign_negative(),
            dir.z.is_sign_negative(),
        ];
        let near = [0, 1, 2].map(|a| if neg[a] { a + 3 } else { a });
        let far = [0, 1, 2].map(|a| if neg[a] { a } else { a + 3 });
        let fits = (0..3).all(|a| {
            let (o, d) = (origin[a].abs(), dir[a].abs());
            o <= SINGLE_MAX && (d == 0.0 || (SINGLE_MIN_DIR..=SINGLE_MAX).contains(&d))
        });
        let inv_dir = DVec3::new(1.0 / safe(dir.x), 1.0 / safe(dir.y), 1.0 / safe(dir.z));
        let single = fits.then(|| {
            let (lo, hi) = (
                origin.to_array().map(round_down),
                origin.to_array().map(round_up),
            );
            Single {
                // Moving up an axis, the entry distance (low − o) must not grow: subtract
                // the larger origin; moving down, (high − o) · (negative) likewise.
                o_near: [0, 1, 2].map(|a| if neg[a] { lo[a] } else { hi[a] }),
                o_far: [0, 1, 2].map(|a| if neg[a] { hi[a] } else { lo[a] }),
                // `1 / d` as computed above: exact for the components that fit, and
                // ±10³⁰⁰ (±∞ in `f32`) for a zero one.
                inv: inv_dir.to_array().map(|i| i as f32),
            }
        });
        Self {
            origin,
            inv_dir,
            near,
            far,
            single,
        }
    }

    /// The entry `λ` of the ray into `[min, max]` clipped to `[t_min, t_max]`, if it enters.
    #[inline(always)]
    pub fn enter(&self, min: DVec3, max: DVec3, t_min: f64, t_max: f64) -> Option<f64> {
        let t0x = (min.x - self.origin.x) * self.inv_dir.x;
        let t1x = (max.x - self.origin.x) * self.inv_dir.x;
        let t0y = (min.y - self.origin.y) * self.inv_dir.y;
        let t1y = (max.y - self.origin.y) * self.inv_dir.y;
        let t0z = (min.z - self.origin.z) * self.inv_dir.z;
        let t1z = (max.z - self.origin.z) * self.inv_dir.z;
        let near = fmax(
            fmax(fmin(t0x, t1x), fmin(t0y, t1y)),
            fmax(fmin(t0z, t1z), t_min),
        );
        let far = fmin(
            fmin(fmax(t0x, t1x), fmax(t0y, t1y)),
            fmin(fmax(t0z, t1z), t_max),
        );
        // 1 + 2γ₃ (pbrt): the far distance is rounded up so grazing rays are not lost.
        (near <= far * (1.0 + 4.0 * f64::EPSILON)).then_some(near)
    }

    /// Tests the four boxes of `b` within `[t_min, t_max]` (`t_min ≥ 0`): a bit per
    /// lane entered, and each lane's entry `λ` rounded down (a lower bound, so a
    /// traversal that skips a box entered beyond its best `λ` never skips one it must
    /// see). Never rejects a box that the ray meets within the interval, grazing its
    /// faces, edges and corners included.
    #[inline(always)]
    pub fn enter4(&self, b: &Boxes4, t_min: f64, t_max: f64) -> (u32, [f32; 4]) {
        match &self.single {
            Some(s) => {
                let mut near = f32x4::splat(t_min as f32);
                let mut far = f32x4::splat(t_max as f32);
                for a in 0..3 {
                    let inv = f32x4::splat(s.inv[a]);
                    let t0 = (f32x4::new(b.planes[self.near[a]]) - f32x4::splat(s.o_near[a])) * inv;
                    let t1 = (f32x4::new(b.planes[self.far[a]]) - f32x4::splat(s.o_far[a])) * inv;
                    near = max_keep(t0, near);
                    far = min_keep(t1, far);
                }
                let near = near * f32x4::splat(SHRINK);
                let hit = near.simd_le(far * f32x4::splat(GROW));
                (hit.to_bitmask(), near.to_array())
            }
            None => self.enter4_f64(b, t_min, t_max),
        }
    }

    /// [`SlabRay::enter4`] in double precision, a lane at a time: for rays whose
    /// numbers are too large or too small for the single-precision test.
    #[cold]
    fn enter4_f64(&self, b: &Boxes4, t_min: f64, t_max: f64) -> (u32, [f32; 4]) {
        let (mut mask, mut out) = (0, [f32::INFINITY; 4]);
        for lane in 0..4 {
            let (mut near, mut far) = (t_min, t_max);
            for a in 0..3 {
                let t0 = (b.planes[self.near[a]][lane] as f64 - self.origin[a]) * self.inv_dir[a];
                let t1 = (b.planes[self.far[a]][lane] as f64 - self.origin[a]) * self.inv_dir[a];
                near = fmax(t0, near);
                far = fmin(t1, far);
            }
            if near <= far * (1.0 + 4.0 * f64::EPSILON) {
                mask |= 1 << lane;
                out[lane] = round_down(near);
            }
        }
        (mask, out)
    }
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
