//! Rendering: the camera's primary rays, Whitted shading, and the tile loop that traces
//! them on rayon. [`Renderer`] holds a scene prepared for tracing; its two kernels say
//! what a pixel reports: a colour ([`ColourKernel`]) or its first hit ([`HitKernel`]).
//!
//! [`Renderer`]: crate::render::Renderer
//! [`ColourKernel`]: crate::render::ColourKernel
//! [`HitKernel`]: crate::render::HitKernel

pub mod camera;
pub mod cost;
pub mod quantise;
pub mod rect;
pub mod shade;
pub mod tiles;

use std::sync::Arc;

use glam::DVec3;

use crate::geometry::{Hit, Ray, Surface, World, ray::PRIMARY_LAMBDA_MIN};
use crate::scene::Scene;
pub use camera::PrimaryRays;
pub use cost::{CostError, Estimate, RayBudget, TooCostly, Work};
pub use quantise::{quantise, quantise8};
pub use rect::{OutsideFrame, ParseRectError, Rect, region_in_frame};
pub use shade::{Conventions, Lecture, RayCount, Shader};
pub use tiles::{
    BAND_PIXELS, Cancel, DEFAULT_TILE_PX, KERNEL_ROWS, Kernel, PACKET_PIXELS, RenderStats,
    Scheduler, SinkClosed, Step, Stopped, Tile, TileCursor, TileShape, TileSink, run, trace_tile,
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
    /// [`Scene::sends_secondaries`], found once for every shader of this render.
    secondaries: bool,
}

impl Renderer {
    /// Builds the acceleration structure (the "build" phase).
    pub fn new(scene: Arc<Scene>) -> Renderer {
        let mut world = scene.world();
        let camera = PrimaryRays::new(&scene);
        world.set_viewpoint(camera.origin());
        Renderer {
            secondaries: scene.sends_secondaries(),
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
        let shader = self.shader();
        let s = self.scene.samples;
        if s == 1 {
            let ray = self.camera.pixel_ray::<C>(u, v);
            return shader.trace_as::<(), C>(&ray, 0, PRIMARY_LAMBDA_MIN, rays, &mut ());
        }
        let [mean] = mean_of_samples(s, |i, j| {
            let ray = self.camera.sample_ray::<C>(u, v, i, j, s);
            [shader.trace_as::<(), C>(&ray, 0, PRIMARY_LAMBDA_MIN, rays, &mut ())]
        });
        mean
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
        let mut record = None;
        if let Some(h) = self.world.closest(&ray, PRIMARY_LAMBDA_MIN, f64::INFINITY) {
            self.put_hit_record::<C>(&ray, &h, &mut record);
        }
        record
    }

    /// The hit data of primary ray `ray`'s first hit `h` under conventions `C`, written
    /// into `slot` by the world ([`World::put_view_surface`]) and, unless `C` takes it as it
    /// is, changed there.
    ///
    /// A record made by a call and then copied into its row was loaded, in part, as a
    /// word its maker wrote in pieces (`object`, `front`, `face`), and each such load
    /// waited for those stores to be written out: about two thirds of the tile loop's
    /// own samples in `classic`'s hit data. Not even copied onto itself, where `C`
    /// leaves it.
    #[inline(always)]
    fn put_hit_record<C: Conventions>(&self, ray: &Ray, h: &Hit, slot: &mut Option<Surface>) {
        self.world.put_view_surface(ray, h, slot);
        if !shade::hit_as_found::<C>()
            && let Some(s) = slot
        {
            let t = &self.scene.objects[h.object as usize].transform;
            *s = shade::conventional_hit::<C>(t, ray, *s);
        }
    }
}

// The packets below are of eight rays, of one row or of the tile loop's two.
const _: () = assert!(PACKET_PIXELS == 8 && KERNEL_ROWS == 2);

/// The pixels of a packet of eight primary rays: a block of `rows` rows (1 or 2) of
/// `8 / rows` pixels from `(u, v)`, lane `k` at `(u + k mod cols, v + k div cols)`.
///
/// Four pixels of each of two rows span less of the image than eight of one, so
/// fewer of the tree's nodes part the packet's rays: `mesh-100k`'s primary packets
/// entered 18 % fewer leaves and 9 % fewer inner nodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packet {
    /// Its first column.
    pub u: u32,
    /// Its first row.
    pub v: u32,
    /// Its rows: 1 or 2.
    pub rows: u32,
}

impl Packet {
    /// Eight pixels of one row from `(u, v)`.
    pub fn row(u: u32, v: u32) -> Packet {
        Packet { u, v, rows: 1 }
    }

    /// Four pixels of each of rows `v` and `v + 1` from column `u`.
    pub fn pair(u: u32, v: u32) -> Packet {
        Packet { u, v, rows: 2 }
    }

    /// Pixels a row.
    #[inline]
    pub fn cols(&self) -> u32 {
        PACKET_PIXELS / self.rows
    }

    /// Lane `k`'s pixel.
    #[inline]
    pub fn pixel(&self, k: usize) -> (u32, u32) {
        let (k, cols) = (k as u32, self.cols());
        (self.u + k % cols, self.v + k / cols)
    }
}

/// `$body` with `$p` bound to packet `$packet` made again with its row count a
/// constant, one copy of `$body` for each shape: lanes' pixels then cost no division,
/// and a row's terms of the camera's mapping are computed once. With the count read
/// at run time, a packet's rays took twice the instructions; with `$body` a closure
/// called from each shape, not inlined, the tile loop 3 to 8 % more.
macro_rules! with_constant_rows {
    ($packet:expr, |$p:ident| $body:expr) => {{
        let q: Packet = $packet;
        match q.rows {
            2 => {
                let $p = Packet::pair(q.u, q.v);
                $body
            }
            _ => {
                let $p = Packet::row(q.u, q.v);
                $body
            }
        }
    }};
}

impl Renderer {
    /// The primary rays of packet `p`'s pixels, lane by lane.
    // Always inlined: called, it was handed its packet through memory, and its load of
    // `(u, v)` as one word waited for their two stores (42 % of its samples).
    #[inline(always)]
    fn pixel_rays8(&self, p: Packet) -> [Ray; 8] {
        with_constant_rows!(p, |p| {
            let mut rays = [Ray::new(DVec3::ZERO, DVec3::ZERO); 8];
            for (k, ray) in rays.iter_mut().enumerate() {
                let (u, v) = p.pixel(k);
                *ray = self.camera.pixel_ray::<Lecture>(u, v);
            }
            rays
        })
    }

    /// The primary rays of sample `(i, j)` (of `s × s`) of packet `p`'s pixels, lane by
    /// lane: [`Renderer::sample_ray`]'s.
    #[inline(always)]
    fn sample_rays8(&self, p: Packet, i: u32, j: u32, s: u32) -> [Ray; 8] {
        with_constant_rows!(p, |p| {
            std::array::from_fn(|k| {
                let (u, v) = p.pixel(k);
                self.camera.sample_ray::<Lecture>(u, v, i, j, s)
            })
        })
    }

    /// Appends [`Renderer::pixel_hit`] of packet `p`'s pixels, their rays traced as a
    /// packet (the same eight hits, bit for bit), to `rows`: those of its first row to
    /// the first, of its second (if it has two) to the second. Each record is made in
    /// its place, not in an array copied there (a hundred bytes a pixel). `bounded` is
    /// [`Renderer::may_meet_objects`] of a block holding the packet.
    #[inline]
    pub fn pixel_hits8(&self, p: Packet, bounded: bool, rows: [&mut Vec<Option<Surface>>; 2]) {
        with_constant_rows!(p, |p| {
            let rays = self.pixel_rays8(p);
            let hits = self.world.closest8(
                &rays,
                true,
                0xff,
                PRIMARY_LAMBDA_MIN,
                f64::INFINITY,
                bounded,
            );
            put_rows(p, rows, |k, row| match &hits[k] {
                None => row.push(None),
                Some(h) => {
                    row.push(None);
                    if let Some(slot) = row.last_mut() {
                        self.put_hit_record::<Lecture>(&rays[k], h, slot);
                    }
                }
            });
        })
    }

    /// Whether a primary ray of some pixel of `block` may meet a bounded object: `false`
    /// where the camera's rays through the block all miss the box around them
    /// ([`PrimaryRays::misses`]), so that only the unbounded objects (planes) need
    /// testing. Asked once for a block of a tile's rows, it spares the sky's packets
    /// their trip into the objects' trees: of `mesh-100k`'s pixels, 63 % miss the
    /// mesh's box.
    #[inline]
    pub fn may_meet_objects(&self, block: Rect) -> bool {
        !self.camera.misses(block, &self.world.bounds())
    }

    /// A shader of this scene for one thread's pixels, one after another: those given
    /// to it in order (a tile's pair of rows, packet by packet) share its shadow hints.
    /// Every shader is made here, so that the scene's materials are scanned once a
    /// render ([`Scene::sends_secondaries`]), not once a shader (a pixel, on some
    /// paths).
    pub fn shader(&self) -> Shader<'_> {
        Shader::new(&self.scene, &self.world, self.secondaries)
    }

    /// [`Renderer::pixel_colour`] of packet `p`'s pixels (lane by lane), their primary
    /// rays traced as a packet and shaded by `shader` (of [`Renderer::shader`]): the
    /// same eight colours, bit for bit, and the same rays counted. In a scene of
    /// several samples a pixel, the eight pixels' sample `(i, j)` is one packet, and
    /// each pixel's samples are added in the order a pixel alone adds them
    /// (`mean_of_samples`). `bounded` is as for [`Renderer::pixel_hits8`] (a block's
    /// cone holds its samples' rays too).
    #[inline]
    pub fn pixel_colours8(
        &self,
        shader: &Shader,
        p: Packet,
        bounded: bool,
        rays: &mut RayCount,
    ) -> [DVec3; 8] {
        match self.scene.samples {
            1 => self.colours8(shader, &self.pixel_rays8(p), bounded, rays),
            s => self.sampled_colours8(shader, p, s, bounded, rays),
        }
    }

    /// [`Renderer::pixel_colours8`] in a scene of `s × s` samples a pixel. A call of
    /// its own: inlined beside the one-sample path, it cost that path 1 % more
    /// instructions.
    #[inline(never)]
    fn sampled_colours8(
        &self,
        shader: &Shader,
        p: Packet,
        s: u32,
        bounded: bool,
        rays: &mut RayCount,
    ) -> [DVec3; 8] {
        mean_of_samples(s, |i, j| {
            self.colours8(shader, &self.sample_rays8(p, i, j, s), bounded, rays)
        })
    }

    /// The colours of eight primary rays, traced and shaded as a packet.
    #[inline(always)]
    fn colours8(
        &self,
        shader: &Shader,
        primary: &[Ray; 8],
        bounded: bool,
        rays: &mut RayCount,
    ) -> [DVec3; 8] {
        let hits = self.world.closest8(
            primary,
            true,
            0xff,
            PRIMARY_LAMBDA_MIN,
            f64::INFINITY,
            bounded,
        );
        shader.shade8(primary, hits, rays)
    }
}

/// The mean of `N` pixels' colours over their `s × s` samples, each sample's from
/// `colour(i, j)` (cell `i` of row `j`): the rows in order, each row's cells in order,
/// added to zero, then divided by `s²`. One order for every caller, so a pixel traced
/// alone and in a packet has the same bits.
#[inline(always)]
fn mean_of_samples<const N: usize>(
    s: u32,
    mut colour: impl FnMut(u32, u32) -> [DVec3; N],
) -> [DVec3; N] {
    let mut sum = [DVec3::ZERO; N];
    for j in 0..s {
        for i in 0..s {
            for (sum, c) in sum.iter_mut().zip(colour(i, j)) {
                *sum += c;
            }
        }
    }
    let sf = s as f64;
    sum.map(|c| c / (sf * sf))
}

/// Appends to `out` the pixels of one or two rows as [`Kernel::rows`] asks, a packet
/// at a time from `packet` while it gives them: blocks of two rows ([`Packet::pair`]),
/// of one ([`Packet::row`]) for a lone row. `packet` traces packet `p`, appends its
/// pixels of its first row to the first of the two vectors it is given and of its
/// second to the second, and counts its rays into `rays`; or appends nothing and says
/// `false`. The pixels no packet gave come from [`Kernel::pixel`].
#[inline]
fn rows_in_packets<K: Kernel>(
    kernel: &K,
    (u, v, width, rows): (u32, u32, u32, u32),
    rays: &mut u64,
    [first, second]: [&mut Vec<K::Pixel>; 2],
    packet: impl Fn(Packet, &mut u64, [&mut Vec<K::Pixel>; 2]) -> bool,
) {
    debug_assert!((1..=KERNEL_ROWS).contains(&rows));
    let mut p = Packet { u, v, rows };
    let cols = p.cols();
    while p.u + cols <= u + width && packet(p, rays, [&mut *first, &mut *second]) {
        p.u += cols;
    }
    for (row, pixels) in (v..v + rows).zip([first, second]) {
        for x in p.u..u + width {
            pixels.push(kernel.pixel(x, row, rays));
        }
    }
}

/// The pixels [`Kernel::rows`] asks for, as a block.
#[inline]
fn block_of((x, y, width, height): (u32, u32, u32, u32)) -> Rect {
    Rect {
        x,
        y,
        width,
        height,
    }
}

/// Appends packet `p`'s eight values to `rows`, lane `k`'s by `put(k, row)`: those of
/// its first row to the first, of its second (if it has two) to the second.
///
/// `put` pushes, rather than returning a value to push, so that a value made in
/// branches is pushed in each: a missed pixel's hit record (`None`, one byte) made as
/// a value beside a hit's was written to the stack and copied whole into the row,
/// each copy's load waiting for that byte's store.
#[inline]
fn put_rows<P>(p: Packet, rows: [&mut Vec<P>; 2], mut put: impl FnMut(usize, &mut Vec<P>)) {
    let cols = p.cols() as usize;
    for (r, out) in rows.into_iter().enumerate().take(p.rows as usize) {
        for k in r * cols..(r + 1) * cols {
            put(k, out);
        }
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
    fn rows(&self, rows: (u32, u32, u32, u32), rays: &mut u64, out: [&mut Vec<[u8; 3]>; 2]) {
        let gamma = self.0.scene.gamma;
        let shader = self.0.shader();
        let bounded = self.0.may_meet_objects(block_of(rows));
        rows_in_packets(self, rows, rays, out, |p, rays, out| {
            let mut n = RayCount(0);
            let c = self.0.pixel_colours8(&shader, p, bounded, &mut n);
            *rays += n.0;
            let q = quantise8(&c, gamma);
            put_rows(p, out, |k, row| row.push(q[k]));
            true
        });
    }
}

/// Reports each pixel's linear colour, before gamma and quantisation: what float images
/// (PFM, OpenEXR) hold. [`ColourKernel`] is this kernel followed by [`fn@quantise`]; kept
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
    fn rows(&self, rows: (u32, u32, u32, u32), rays: &mut u64, out: [&mut Vec<[f32; 3]>; 2]) {
        let shader = self.0.shader();
        let bounded = self.0.may_meet_objects(block_of(rows));
        rows_in_packets(self, rows, rays, out, |p, rays, out| {
            let mut n = RayCount(0);
            let c = self.0.pixel_colours8(&shader, p, bounded, &mut n);
            *rays += n.0;
            put_rows(p, out, |k, row| row.push(c[k].as_vec3().to_array()));
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
    fn rows(
        &self,
        rows: (u32, u32, u32, u32),
        rays: &mut u64,
        out: [&mut Vec<Option<Surface>>; 2],
    ) {
        let bounded = self.0.may_meet_objects(block_of(rows));
        rows_in_packets(self, rows, rays, out, |p, rays, out| {
            *rays += u64::from(PACKET_PIXELS);
            self.0.pixel_hits8(p, bounded, out);
            true
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Reports where each pixel is and whether a packet gave it, refusing the packets
    /// `refuse` says, and keeps the packets it made.
    struct Where<F> {
        refuse: F,
        made: std::sync::Mutex<Vec<Packet>>,
    }

    impl<F: Fn(Packet) -> bool + Sync> Kernel for Where<F> {
        type Pixel = (u32, u32, bool);
        fn pixel(&self, u: u32, v: u32, rays: &mut u64) -> (u32, u32, bool) {
            *rays += 1;
            (u, v, false)
        }

        fn rows(
            &self,
            rows: (u32, u32, u32, u32),
            rays: &mut u64,
            out: [&mut Vec<Self::Pixel>; 2],
        ) {
            rows_in_packets(self, rows, rays, out, |p, rays, out| {
                if (self.refuse)(p) {
                    return false;
                }
                self.made.lock().expect("not poisoned").push(p);
                *rays += 8;
                put_rows(p, out, |k, row| {
                    let (x, y) = p.pixel(k);
                    row.push((x, y, true));
                });
                true
            });
        }
    }

    /// The tile loop's pixels of `width` × `rows` from `(u, v)` with a [`Where`]
    /// kernel, the packets made, and the rays counted.
    fn fill(
        (u, v, width, rows): (u32, u32, u32, u32),
        refuse: impl Fn(Packet) -> bool + Sync,
    ) -> (Vec<(u32, u32, bool)>, Vec<Packet>, u64) {
        let kernel = Where {
            refuse,
            made: Default::default(),
        };
        let r = Rect {
            x: u,
            y: v,
            width,
            height: rows,
        };
        let tile = trace_tile(&kernel, r, &Cancel::new()).expect("never cancelled");
        let made = kernel.made.into_inner().expect("not poisoned");
        (tile.pixels, made, tile.rays)
    }

    #[test]
    fn packets_put_every_pixel_in_its_place_two_rows_at_a_time() {
        for (width, rows) in [(16, 2), (13, 2), (9, 1), (21, 1), (3, 2), (8, 3), (12, 4)] {
            let (u, v) = (5, 7);
            let (out, made, rays) = fill((u, v, width, rows), |_| false);
            assert_eq!(out.len() as u32, width * rows);
            for (i, &(x, y, _)) in out.iter().enumerate() {
                let i = i as u32;
                assert_eq!((x, y), (u + i % width, v + i / width), "{width}×{rows}");
            }
            assert_eq!(rays, u64::from(width * rows), "every pixel's ray counted");
            // Pairs of rows go in blocks of 4 × 2, a last lone row in rows of 8; the
            // pixels past the last whole packet of a row alone.
            for p in &made {
                let pair = p.v + 1 < v + rows && (p.v - v) % 2 == 0;
                assert_eq!(p.rows, if pair { 2 } else { 1 }, "{width}×{rows}: {p:?}");
            }
            let in_packets = out.iter().filter(|p| p.2).count() as u32;
            let pairs = rows / 2 * (width / 4 * 8);
            let lone = rows % 2 * (width / 8 * 8);
            assert_eq!(in_packets, pairs + lone, "{width}×{rows}");
        }
    }

    #[test]
    fn a_refused_packet_leaves_the_rest_of_its_rows_to_single_pixels() {
        let (width, rows) = (16, 3);
        let (out, made, _) = fill((0, 0, width, rows), |p| p.u == 4 && p.rows == 2);
        assert_eq!(
            made,
            [Packet::pair(0, 0), Packet::row(0, 2), Packet::row(8, 2)]
        );
        for (i, &(x, y, packed)) in out.iter().enumerate() {
            let i = i as u32;
            assert_eq!((x, y), (i % width, i / width));
            assert_eq!(packed, y == 2 || x < 4, "({x}, {y})");
        }
    }
}
