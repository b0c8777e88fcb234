//! A small Whitted ray tracer written from the specification alone (`docs/spec/`), for
//! spheres and planes placed by scale-then-translate, point lights and a camera at the
//! origin: what a student hands in. Each [`Flags`] field makes it commit one classic
//! mistake of the course, so the diagnosis is tested on mistakes made by code that shares
//! nothing with the grader.

#![allow(dead_code)]

use glam::DVec3;
use serde_json::{Value, json};

/// A canonical shape.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// The unit sphere.
    Sphere,
    /// The plane `y = 0`.
    Plane,
}

/// A material, every field given.
#[derive(Debug, Clone, Copy)]
pub struct Material {
    pub ambient: DVec3,
    pub diffuse: DVec3,
    pub specular: DVec3,
    pub shininess: f64,
    pub mirror: DVec3,
    pub transmission: DVec3,
    pub ior: f64,
}

/// An object: `T = translate(t) · scale(s)`.
#[derive(Debug, Clone, Copy)]
pub struct Object {
    pub shape: Shape,
    pub scale: DVec3,
    pub translate: DVec3,
    pub material: Material,
}

/// A scene with its camera at the origin looking along +z, y down.
#[derive(Debug, Clone)]
pub struct Scene {
    pub width: u32,
    pub height: u32,
    pub gamma: Option<f64>,
    pub background: DVec3,
    pub ambient: DVec3,
    pub max_depth: u32,
    pub objects: Vec<Object>,
    /// Point lights: position, colour.
    pub lights: Vec<(DVec3, DVec3)>,
}

/// The mistakes the tracer can make.
#[derive(Debug, Clone, Copy, Default)]
pub struct Flags {
    pub y_up: bool,
    pub x_left: bool,
    pub uv_swapped: bool,
    pub bgr: bool,
    pub no_gamma: bool,
    pub gamma_twice: bool,
    pub srgb: bool,
    pub gamma_unasked: bool,
    pub truncate: bool,
    pub corner: bool,
    pub unit_lambda: bool,
    pub forward_normals: bool,
    pub raw_normals: bool,
    pub no_shadow_offset: bool,
    pub no_shadows: bool,
    pub no_ambient: bool,
    pub no_specular: bool,
    pub blinn: bool,
    pub no_reflection: bool,
    pub no_refraction: bool,
    pub inverted_eta: bool,
    pub depth_delta: i64,
}

fn v3(x: DVec3) -> Value {
    json!([x.x, x.y, x.z])
}

impl Scene {
    /// The scene as a raytile document.
    pub fn document(&self) -> Value {
        let mut image = json!({"width": self.width, "height": self.height});
        if let Some(g) = self.gamma {
            image["gamma"] = json!(g);
        }
        let objects: Vec<Value> = self
            .objects
            .iter()
            .map(|o| {
                let m = &o.material;
                json!({
                    "shape": match o.shape { Shape::Sphere => "sphere", Shape::Plane => "plane" },
                    "transform": [{"scale": v3(o.scale)}, {"translate": v3(o.translate)}],
                    "material": {
                        "ambient": v3(m.ambient), "diffuse": v3(m.diffuse),
                        "specular": v3(m.specular), "shininess": m.shininess,
                        "mirror": v3(m.mirror), "transmission": v3(m.transmission),
                        "ior": m.ior,
                    },
                })
            })
            .collect();
        let lights: Vec<Value> = self
            .lights
            .iter()
            .map(|(p, c)| json!({"type": "point", "position": v3(*p), "colour": v3(*c)}))
            .collect();
        json!({
            "version": 1,
            "image": image,
            "background": v3(self.background),
            "ambient": v3(self.ambient),
            "max_depth": self.max_depth,
            "objects": objects,
            "lights": lights,
        })
    }
}

/// A first hit as the tracer reports it.
#[derive(Debug, Clone, Copy)]
pub struct Hit {
    pub lambda: f64,
    pub object: usize,
    pub point: DVec3,
    /// As reported: outward for spheres, facing the ray's origin for the plane.
    pub normal: DVec3,
    /// Whether the ray met the outside (`n · d < 0` before any turning).
    pub front: bool,
}

pub struct Tracer<'a> {
    pub scene: &'a Scene,
    pub flags: Flags,
}

impl Tracer<'_> {
    fn primary(&self, u: u32, v: u32) -> DVec3 {
        let (w, h) = (self.scene.width as f64, self.scene.height as f64);
        let o = if self.flags.corner { 0.0 } else { 0.5 };
        let (mut x, mut y) = (u as f64 + o, v as f64 + o);
        if self.flags.uv_swapped {
            std::mem::swap(&mut x, &mut y);
        }
        let mut d = DVec3::new(-1.0 + x * 2.0 / w, -h / w + y * 2.0 / w, 1.0);
        if self.flags.y_up {
            d.y = -d.y;
        }
        if self.flags.x_left {
            d.x = -d.x;
        }
        d
    }

    /// The smallest `λ` in `(t_min, t_max)` over every object.
    fn closest(&self, o: DVec3, d: DVec3, t_min: f64, t_max: f64) -> Option<Hit> {
        let mut best: Option<(f64, usize)> = None;
        for (k, ob) in self.scene.objects.iter().enumerate() {
            let (po, dobj) = ((o - ob.translate) / ob.scale, d / ob.scale);
            let t = match ob.shape {
                Shape::Sphere => {
                    let a = dobj.dot(dobj);
                    let b = 2.0 * po.dot(dobj);
                    let c = po.dot(po) - 1.0;
                    let disc = b * b - 4.0 * a * c;
                    if disc < 0.0 || a == 0.0 {
                        None
                    } else {
                        let s = disc.sqrt();
                        [(-b - s) / (2.0 * a), (-b + s) / (2.0 * a)]
                            .into_iter()
                            .find(|&t| t > t_min && t < t_max)
                    }
                }
                Shape::Plane => {
                    if dobj.y.abs() < 1e-12 {
                        None
                    } else {
                        Some(-po.y / dobj.y).filter(|&t| t > t_min && t < t_max)
                    }
                }
            };
            if let Some(t) = t
                && best.is_none_or(|(b, _)| t < b)
            {
                best = Some((t, k));
            }
        }
        let (lambda, k) = best?;
        let ob = &self.scene.objects[k];
        let object_point = (o - ob.translate) / ob.scale + lambda * (d / ob.scale);
        let n_object = match ob.shape {
            Shape::Sphere => object_point,
            Shape::Plane => DVec3::Y,
        };
        let carried = if self.flags.forward_normals {
            n_object * ob.scale
        } else {
            n_object / ob.scale
        };
        let mut normal = if self.flags.raw_normals {
            carried
        } else {
            carried.normalize()
        };
        let front = normal.dot(d) < 0.0;
        if ob.shape == Shape::Plane && !front {
            normal = -normal;
        }
        Some(Hit {
            lambda,
            object: k,
            point: o + lambda * d,
            normal,
            front,
        })
    }

    fn trace(&self, o: DVec3, d: DVec3, depth: u32, t_min: f64) -> DVec3 {
        let Some(hit) = self.closest(o, d, t_min, f64::INFINITY) else {
            return self.scene.background;
        };
        let f = &self.flags;
        let m = self.scene.objects[hit.object].material;
        let n = if hit.normal.dot(d) < 0.0 {
            hit.normal
        } else {
            -hit.normal
        };
        let p = hit.point;
        let eps = 1e-9 * p.abs().max_element().max(1.0);
        let mut c = if f.no_ambient {
            DVec3::ZERO
        } else {
            self.scene.ambient * m.ambient
        };
        let view = -d.normalize();
        for &(q, colour) in &self.scene.lights {
            let origin = if f.no_shadow_offset { p } else { p + eps * n };
            let to_light = q - origin;
            let l = to_light.normalize();
            let nl = n.dot(l);
            let r = 2.0 * nl * n - l;
            let diffuse = colour * m.diffuse * nl.max(0.0);
            let mut specular = DVec3::ZERO;
            if !f.no_specular && m.specular != DVec3::ZERO {
                let cosine = if f.blinn {
                    n.dot((l + view).normalize())
                } else {
                    r.dot(view)
                };
                specular = colour * m.specular * cosine.max(0.0).powf(m.shininess);
            }
            let lit = diffuse + specular;
            if lit == DVec3::ZERO {
                continue;
            }
            let t_min = if f.no_shadow_offset { 0.0 } else { 1e-9 };
            let blocked = !f.no_shadows && self.closest(origin, to_light, t_min, 1.0).is_some();
            if !blocked {
                c += lit;
            }
        }
        let max_depth = self.scene.max_depth as i64 + f.depth_delta;
        if (m.mirror != DVec3::ZERO || m.transmission != DVec3::ZERO) && (depth as i64) < max_depth
        {
            let i = d.normalize();
            let cos_i = -n.dot(i);
            let (ro, rd) = (p + eps * n, i + 2.0 * cos_i * n);
            let entering = hit.front != f.inverted_eta;
            let eta = if entering { 1.0 / m.ior } else { m.ior };
            let k = 1.0 - eta * eta * (1.0 - cos_i * cos_i);
            let (to, td) = if k < 0.0 {
                (ro, rd)
            } else {
                (
                    p - eps * n,
                    (eta * i + (eta * cos_i - k.sqrt()) * n).normalize(),
                )
            };
            if m.mirror != DVec3::ZERO && !f.no_reflection {
                c += m.mirror * self.trace(ro, rd, depth + 1, 1e-9);
            }
            if m.transmission != DVec3::ZERO && !f.no_refraction {
                c += m.transmission * self.trace(to, td, depth + 1, 1e-9);
            }
        }
        c
    }

    fn srgb(c: f64) -> f64 {
        if c <= 0.0031308 {
            12.92 * c
        } else {
            1.055 * c.powf(1.0 / 2.4) - 0.055
        }
    }

    /// The image as RGB bytes, row by row.
    pub fn image(&self) -> Vec<u8> {
        let f = &self.flags;
        let mut out = Vec::new();
        for v in 0..self.scene.height {
            for u in 0..self.scene.width {
                let c = self.trace(DVec3::ZERO, self.primary(u, v), 0, 1e-9);
                let mut rgb = [c.x, c.y, c.z].map(|x| {
                    let x = x.clamp(0.0, 1.0);
                    let g = self.scene.gamma.unwrap_or(1.0);
                    let x = if f.srgb {
                        Self::srgb(x)
                    } else if f.gamma_unasked {
                        x.powf(1.0 / 2.2)
                    } else if f.no_gamma {
                        x
                    } else if f.gamma_twice {
                        x.powf(1.0 / g).powf(1.0 / g)
                    } else {
                        x.powf(1.0 / g)
                    };
                    if f.truncate {
                        (255.0 * x).floor() as u8
                    } else {
                        (255.0 * x).round() as u8
                    }
                });
                if f.bgr {
                    rgb.swap(0, 2);
                }
                out.extend_from_slice(&rgb);
            }
        }
        out
    }

    /// The hit data as the JSON pixel records of `docs/spec/hit-data.md`.
    pub fn hits(&self) -> Vec<Value> {
        let mut out = Vec::new();
        for v in 0..self.scene.height {
            for u in 0..self.scene.width {
                let d = self.primary(u, v);
                out.push(match self.closest(DVec3::ZERO, d, 1e-9, f64::INFINITY) {
                    None => json!({"u": u, "v": v, "hit": false}),
                    Some(h) => {
                        let lambda = if self.flags.unit_lambda {
                            h.lambda * d.length()
                        } else {
                            h.lambda
                        };
                        json!({"u": u, "v": v, "hit": true, "object": h.object,
                               "lambda": lambda, "normal": v3(h.normal)})
                    }
                });
            }
        }
        out
    }
}
