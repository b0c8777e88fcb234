//! Whitted ray tracing with the Phong model (SPEC §3).
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

use glam::DVec3;

use crate::geometry::{Ray, Surface, World};
use crate::scene::{Light, Material, Scene};

/// Smallest `λ` of a secondary ray's hit.
pub const SECONDARY_LAMBDA_MIN: f64 = 1e-9;

/// How far off the surface secondary rays start: `1e-9 · max(1, |p|∞)`, far above the
/// rounding error of a hit point in f64 and far below anything visible.
#[inline]
pub fn surface_offset(p: DVec3) -> f64 {
    1e-9 * p.abs().max_element().max(1.0)
}

/// Counts the rays a pixel costs (primary and secondary).
#[derive(Debug, Default, Clone, Copy)]
pub struct RayCount(pub u64);

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

/// The directions a surface sends secondary rays in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounce {
    /// The mirror ray.
    pub reflected: Ray,
    /// The refracted ray, or the reflected one under total internal reflection.
    pub refracted: Ray,
    /// Whether the refracted ray is really a total internal reflection.
    pub total_internal_reflection: bool,
}

/// The normal turned to face the incoming ray.
#[inline]
pub fn facing_normal(s: &Surface, dir: DVec3) -> DVec3 {
    if s.normal.dot(dir) < 0.0 {
        s.normal
    } else {
        -s.normal
    }
}

/// One light's terms at a surface point seen along `dir`, its shadow ray traced.
#[inline]
pub fn light_term(
    world: &World,
    light: &Light,
    s: &Surface,
    n: DVec3,
    dir: DVec3,
    m: &Material,
) -> LightTerm {
    let mut term = unshadowed_light_term(light, s, n, dir, m);
    if !term.outside_cone {
        term.blocked = world.occluded(&term.shadow_ray, SECONDARY_LAMBDA_MIN, term.shadow_t_max);
        if term.blocked {
            term.diffuse = DVec3::ZERO;
            term.specular = DVec3::ZERO;
        }
    }
    term
}

/// One light's terms as if nothing blocked it; the shadow ray is made, not traced.
#[inline]
pub fn unshadowed_light_term(
    light: &Light,
    s: &Surface,
    n: DVec3,
    dir: DVec3,
    m: &Material,
) -> LightTerm {
    let origin = s.point + n * surface_offset(s.point);
    let (to_light, t_max, colour, outside) = match *light {
        Light::Point { position, colour } => (position - origin, 1.0, colour, false),
        Light::Directional { direction, colour } => (-direction, f64::INFINITY, colour, false),
        Light::Spot {
            position,
            direction,
            cos_angle,
            colour,
        } => {
            let inside = (s.point - position).normalize().dot(direction) >= cos_angle;
            (position - origin, 1.0, colour, !inside)
        }
    };
    let mut term = LightTerm {
        shadow_ray: Ray::new(origin, to_light),
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
    let l = to_light.normalize();
    let v = -dir.normalize();
    let n_dot_l = n.dot(l);
    let r = 2.0 * n_dot_l * n - l;
    let r_dot_v = r.dot(v);
    term.l = l;
    term.n_dot_l = n_dot_l;
    term.r_dot_v = r_dot_v;
    term.diffuse = colour * m.diffuse * n_dot_l.max(0.0);
    // `pow` is the costliest step of shading; a black specular needs none.
    if m.specular != DVec3::ZERO {
        term.specular = colour * m.specular * r_dot_v.max(0.0).powf(m.shininess);
    }
    term
}

/// The reflected and refracted rays at a surface point hit along `dir`, with `ior` the
/// material's index (entering from air when the ray meets the outside of the surface).
#[inline]
pub fn bounce(s: &Surface, n: DVec3, dir: DVec3, ior: f64) -> Bounce {
    let i = dir.normalize();
    let off = surface_offset(s.point);
    let outside = s.point + n * off;
    let inside = s.point - n * off;
    let cos_i = -n.dot(i);
    let reflected = Ray::new(outside, i + 2.0 * cos_i * n);
    let eta = if s.front { 1.0 / ior } else { ior };
    let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
    if k < 0.0 {
        Bounce {
            reflected,
            refracted: reflected,
            total_internal_reflection: true,
        }
    } else {
        let t = eta * i + (eta * cos_i - k.sqrt()) * n;
        Bounce {
            reflected,
            refracted: Ray::new(inside, t.normalize()),
            total_internal_reflection: false,
        }
    }
}

/// A scene and its world, ready to shade rays.
pub struct Shader<'a> {
    /// The scene.
    pub scene: &'a Scene,
    /// Its acceleration structure.
    pub world: &'a World,
}

impl Shader<'_> {
    /// The colour seen along `ray`, a ray at recursion `depth`.
    pub fn trace(&self, ray: &Ray, depth: u32, t_min: f64, rays: &mut RayCount) -> DVec3 {
        rays.0 += 1;
        let Some(hit) = self.world.closest(ray, t_min, f64::INFINITY) else {
            return self.scene.background;
        };
        let s = self.world.surface(ray, &hit);
        let m = &self.scene.materials[self.scene.objects[hit.object as usize].material as usize];
        let n = facing_normal(&s, ray.dir);
        let mut c = self.scene.ambient * m.ambient;
        for light in &self.scene.lights {
            let t = unshadowed_light_term(light, &s, n, ray.dir, m);
            let lit = t.diffuse + t.specular;
            // A light that would add nothing needs no shadow ray.
            if t.outside_cone || lit == DVec3::ZERO {
                continue;
            }
            rays.0 += 1;
            if !self
                .world
                .occluded(&t.shadow_ray, SECONDARY_LAMBDA_MIN, t.shadow_t_max)
            {
                c += lit;
            }
        }
        if depth < self.scene.max_depth
            && (m.mirror != DVec3::ZERO || m.transmission != DVec3::ZERO)
        {
            let b = bounce(&s, n, ray.dir, m.ior);
            if m.mirror != DVec3::ZERO {
                c += m.mirror * self.trace(&b.reflected, depth + 1, SECONDARY_LAMBDA_MIN, rays);
            }
            if m.transmission != DVec3::ZERO {
                c += m.transmission
                    * self.trace(&b.refracted, depth + 1, SECONDARY_LAMBDA_MIN, rays);
            }
        }
        c
    }
}

/// Linear colour to 8 bits: optional gamma, then `round(255 · clamp(c, 0, 1))`.
#[inline]
pub fn quantise(c: DVec3, gamma: Option<f64>) -> [u8; 3] {
    let c = match gamma {
        Some(g) => DVec3::new(c.x.powf(1.0 / g), c.y.powf(1.0 / g), c.z.powf(1.0 / g)),
        None => c,
    };
    let q = |x: f64| (255.0 * x.clamp(0.0, 1.0)).round() as u8;
    [q(c.x), q(c.y), q(c.z)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantise_rounds_and_clamps() {
        assert_eq!(quantise(DVec3::new(0.5, 2.0, -1.0), None), [128, 255, 0]);
        assert_eq!(quantise(DVec3::splat(0.25), Some(2.0)), [128, 128, 128]);
    }
}
