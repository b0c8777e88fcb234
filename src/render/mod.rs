//! Rendering: the camera's primary rays, Whitted shading, and the tile loop that traces
//! them on rayon. [`Renderer`] holds a scene prepared for tracing; its two kernels say
//! what a pixel reports: a colour ([`ColourKernel`]) or its first hit ([`HitKernel`]).

pub mod camera;
pub mod cost;
pub mod rect;
pub mod shade;
pub mod tiles;

use std::sync::Arc;

use glam::DVec3;

use crate::geometry::{Hit, Ray, Surface, World, ray::PRIMARY_LAMBDA_MIN};
use crate::scene::Scene;
pub use camera::PrimaryRays;
pub use cost::{CostError, Estimate, RayBudget, TooCostly, Work};
pub use rect::{OutsideFrame, ParseRectError, Rect, region_in_frame};
pub use shade::{Conventions, Lecture, RayCount, Shader, quantise};
pub use tiles::{
    BAND_PIXELS, Cancel, DEFAULT_TILE_PX, Kernel, PACKET_PIXELS, RenderStats, Scheduler,
    SinkClosed, Step, Stopped, Tile, TileCursor, TileShape, TileSink, run, trace_tile,
};

/// A scene prepared for tracing: its acceleration structure and camera.
#[derive(Debug, Clone)]
pub struct Renderer {
    /// The scene.
    pub scene: Arc<Scene>,
    /// Its objects, indexed.
    pub world: World,
    /// Its camera.
    pub camera: PrimaryRays,
}

impl Renderer {
    /// Builds the acceleration structure (the "build" phase).
    pub fn new(scene: Arc<Scene>) -> Renderer {
        let mut world = scene.world();
        let camera = PrimaryRays::new(&scene);
        world.set_viewpoint(camera.origin());
        Renderer {
            scene,
            world,
            camera,
        }
    }

    /// The full frame.
    pub fn frame(&self) -> Rect {
        Rect::frame(self.scene.width, self.scene.height)
    }

    /// The linear colour of pixel `(u, v)`: the mean of its `s × s` samples.
    #[inline]
    pub fn pixel_colour(&self, u: u32, v: u32, rays: &mut RayCount) -> DVec3 {
        self.pixel_colour_as::<Lecture>(u, v, rays)
    }

    /// [`Renderer::pixel_colour`] traced under conventions `C`.
    pub fn pixel_colour_as<C: Conventions>(&self, u: u32, v: u32, rays: &mut RayCount) -> DVec3 {
        let shader = Shader::new(&self.scene, &self.world);
        let s = self.scene.samples;
        if s == 1 {
            let ray = self.camera.pixel_ray::<C>(u, v);
            return shader.trace_as::<(), C>(&ray, 0, PRIMARY_LAMBDA_MIN, rays, &mut ());
        }
        let sf = s as f64;
        let mut sum = DVec3::ZERO;
        for j in 0..s {
            for i in 0..s {
                let ray = self.camera.sample_ray::<C>(u, v, i, j, s);
                sum += shader.trace_as::<(), C>(&ray, 0, PRIMARY_LAMBDA_MIN, rays, &mut ());
            }
        }
        sum / (sf * sf)
    }

    /// The primary ray of sample `(i, j)` of pixel `(u, v)`: the centre of cell `(i, j)`
    /// of the pixel cut into `samples × samples` cells.
    #[inline]
    pub fn sample_ray(&self, u: u32, v: u32, i: u32, j: u32) -> Ray {
        self.camera
            .sample_ray::<Lecture>(u, v, i, j, self.scene.samples)
    }

    /// The first hit of pixel `(u, v)`'s centre ray.
    #[inline]
    pub fn pixel_hit(&self, u: u32, v: u32) -> Option<Surface> {
        self.pixel_hit_as::<Lecture>(u, v)
    }

    /// [`Renderer::pixel_hit`] under conventions `C` (its primary ray only).
    #[inline]
    pub fn pixel_hit_as<C: Conventions>(&self, u: u32, v: u32) -> Option<Surface> {
        let ray = self.camera.pixel_ray::<C>(u, v);
        self.world
            .closest(&ray, PRIMARY_LAMBDA_MIN, f64::INFINITY)
            .map(|h| self.hit_record::<C>(&ray, &h))
    }

    /// The hit data of primary ray `ray`'s first hit `h`, under conventions `C`.
    #[inline]
    fn hit_record<C: Conventions>(&self, ray: &Ray, h: &Hit) -> Surface {
        shade::conventional_hit::<C>(
            &self.scene.objects[h.object as usize].transform,
            ray,
            self.world.surface(ray, h),
        )
    }
}

// The packets below are of eight rays, a packet's pixels in a row.
const _: () = assert!(PACKET_PIXELS == 8);

impl Renderer {
    /// The primary rays of pixels `(u, v)` to `(u + 7, v)`.
    #[inline]
    fn pixel_rays8(&self, u: u32, v: u32) -> [Ray; 8] {
        let mut rays = [Ray::new(DVec3::ZERO, DVec3::ZERO); 8];
        for (k, r) in rays.iter_mut().enumerate() {
            *r = self.camera.pixel_ray::<Lecture>(u + k as u32, v);
        }
        rays
    }

    /// Appends to `out` [`Renderer::pixel_hit`] of pixels `(u, v)` to `(u + 7, v)`,
    /// their rays traced as a packet: the same eight hits, bit for bit. Each record is
    /// made in its place in `out`, not in an array copied there (a hundred bytes a
    /// pixel).
    #[inline]
    pub fn pixel_hits8(&self, u: u32, v: u32, out: &mut Vec<Option<Surface>>) {
        let rays = self.pixel_rays8(u, v);
        let hits = self
            .world
            .closest8(&rays, PRIMARY_LAMBDA_MIN, f64::INFINITY);
        out.extend(
            hits.iter()
                .zip(&rays)
                .map(|(h, ray)| h.map(|h| self.hit_record::<Lecture>(ray, &h))),
        );
    }

    /// A shader of this scene for one thread's pixels, one after another: those of a
    /// row given to it in order share its shadow hints ([`Shader::new`]).
    pub fn shader(&self) -> Shader<'_> {
        Shader::new(&self.scene, &self.world)
    }

    /// [`Renderer::pixel_colour`] of pixels `(u, v)` to `(u + 7, v)` of a scene of one
    /// sample a pixel, their primary rays traced as a packet and shaded by `shader`
    /// (of [`Renderer::shader`]): the same eight colours, bit for bit. `None` for a
    /// scene of several samples a pixel.
    #[inline]
    pub fn pixel_colours8(
        &self,
        shader: &Shader,
        u: u32,
        v: u32,
        rays: &mut RayCount,
    ) -> Option<[DVec3; 8]> {
        if self.scene.samples != 1 {
            return None;
        }
        let primary = self.pixel_rays8(u, v);
        let hits = self
            .world
            .closest8(&primary, PRIMARY_LAMBDA_MIN, f64::INFINITY);
        Some(shader.shade8(&primary, hits, rays))
    }
}

/// Pixels `(u, v)` to `(u + width − 1, v)` into `out`: [`PACKET_PIXELS`] at a time
/// from `packet` (which appends them to `out` and counts its rays into `rays`, or
/// appends nothing and says `false`) while it gives them, the rest from the kernel's
/// own [`Kernel::pixel`].
#[inline]
fn row_in_packets<K: Kernel>(
    kernel: &K,
    (u, v, width): (u32, u32, u32),
    rays: &mut u64,
    out: &mut Vec<K::Pixel>,
    packet: impl Fn(u32, &mut u64, &mut Vec<K::Pixel>) -> bool,
) {
    let mut x = u;
    while x + PACKET_PIXELS <= u + width && packet(x, rays, out) {
        x += PACKET_PIXELS;
    }
    for x in x..u + width {
        out.push(kernel.pixel(x, v, rays));
    }
}

/// Reports each pixel's 8-bit RGB colour.
pub struct ColourKernel<'a>(pub &'a Renderer);

impl Kernel for ColourKernel<'_> {
    type Pixel = [u8; 3];
    #[inline]
    fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> [u8; 3] {
        let mut n = RayCount(0);
        let c = self.0.pixel_colour(u, v, &mut n);
        *rays += n.0;
        quantise(c, self.0.scene.gamma)
    }

    #[inline]
    fn row(&self, u: u32, v: u32, width: u32, rays: &mut u64, out: &mut Vec<[u8; 3]>) {
        let gamma = self.0.scene.gamma;
        let shader = self.0.shader();
        row_in_packets(self, (u, v, width), rays, out, |x, rays, out| {
            let mut n = RayCount(0);
            let Some(c) = self.0.pixel_colours8(&shader, x, v, &mut n) else {
                return false;
            };
            *rays += n.0;
            out.extend(c.map(|c| quantise(c, gamma)));
            true
        });
    }
}

/// Reports each pixel's linear colour, before gamma and quantisation: what float images
/// (PFM, OpenEXR) hold. [`ColourKernel`] is this kernel followed by [`quantise`]; kept
/// apart so that the 8-bit path stays as it is.
pub struct LinearKernel<'a>(pub &'a Renderer);

impl Kernel for LinearKernel<'_> {
    type Pixel = [f32; 3];
    #[inline]
    fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> [f32; 3] {
        let mut n = RayCount(0);
        let c = self.0.pixel_colour(u, v, &mut n);
        *rays += n.0;
        c.as_vec3().to_array()
    }

    #[inline]
    fn row(&self, u: u32, v: u32, width: u32, rays: &mut u64, out: &mut Vec<[f32; 3]>) {
        let shader = self.0.shader();
        row_in_packets(self, (u, v, width), rays, out, |x, rays, out| {
            let mut n = RayCount(0);
            let Some(c) = self.0.pixel_colours8(&shader, x, v, &mut n) else {
                return false;
            };
            *rays += n.0;
            out.extend(c.map(|c| c.as_vec3().to_array()));
            true
        });
    }
}

/// Reports each pixel's first hit (`docs/spec/hit-data.md`).
pub struct HitKernel<'a>(pub &'a Renderer);

impl Kernel for HitKernel<'_> {
    type Pixel = Option<Surface>;
    #[inline]
    fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> Option<Surface> {
        *rays += 1;
        self.0.pixel_hit(u, v)
    }

    #[inline]
    fn row(&self, u: u32, v: u32, width: u32, rays: &mut u64, out: &mut Vec<Option<Surface>>) {
        row_in_packets(self, (u, v, width), rays, out, |x, rays, out| {
            *rays += u64::from(PACKET_PIXELS);
            self.0.pixel_hits8(x, v, out);
            true
        });
    }
}
