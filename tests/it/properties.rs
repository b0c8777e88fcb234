//! Properties that hold for any scene: the BVH finds what testing every object finds;
//! moving the camera and every object together changes nothing; the output does not
//! depend on tiles or threads.

use std::sync::Arc;

use glam::DVec3;
use raytile::geometry::{Ray, Rays8, ShadowHint};
use raytile::render::{Packet, Rect, Renderer};
use raytile::scene::{Limits, parse};
use serde_json::{Value, json};

use crate::support::*;

/// A small deterministic generator (xorshift64*), so failures reproduce.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
    fn v3(&mut self, lo: f64, hi: f64) -> [f64; 3] {
        [self.range(lo, hi), self.range(lo, hi), self.range(lo, hi)]
    }
}

const SHAPES: [&str; 7] = [
    "sphere", "cube", "disk", "cylinder", "cone", "mesh", "plane",
];

/// A random scene of `n` objects of every shape, rotated and non-uniformly scaled.
fn random_scene(seed: u64, n: usize, size: u32) -> Value {
    let mut r = Rng(seed);
    let mut objects = Vec::new();
    for i in 0..n {
        let shape = SHAPES[if i == n - 1 { 6 } else { i % 6 }];
        // A quarter mirrors, a quarter glass (half of that mirroring too), so that hits
        // send reflected rays, refracted ones and both.
        let mirror = if i % 4 == 0 || i % 8 == 1 { 0.3 } else { 0.0 };
        let transmission = if i % 4 == 1 { 0.6 } else { 0.0 };
        let mut o = json!({
            "shape": shape,
            "material": {
                "diffuse": r.v3(0.1, 0.9),
                "mirror": [mirror, mirror, mirror],
                "transmission": [transmission, transmission, transmission],
                "ior": 1.5
            },
            "transform": [
                {"scale": r.v3(0.2, 1.2)},
                {"rotate": {"axis": r.v3(-1.0, 1.0), "degrees": r.range(0.0, 360.0)}},
                {"translate": [r.range(-6.0, 6.0), r.range(-4.0, 4.0), r.range(4.0, 20.0)]}
            ]
        });
        if shape == "plane" {
            // A floor below the objects (camera y points down), falling away from the
            // camera, so that the objects stand in front of it.
            o["transform"] =
                json!([{"rotate": {"axis": "x", "degrees": -10}}, {"translate": [0, 5, 0]}]);
        }
        if shape == "mesh" {
            let positions: Vec<[f64; 3]> = (0..12).map(|_| r.v3(-1.0, 1.0)).collect();
            let indices: Vec<[u32; 3]> = (0..10).map(|k| [k, k + 1, k + 2]).collect();
            o["positions"] = json!(positions);
            o["indices"] = json!(indices);
        }
        objects.push(o);
    }
    json!({
        "version": 1,
        "image": {"width": size, "height": size * 3 / 4},
        "camera": {"focal_length": 1.2},
        "ambient": [0.1, 0.1, 0.1],
        "max_depth": 2,
        "objects": objects,
        "lights": [{"type": "point", "position": [3, -8, 0], "colour": [0.8, 0.8, 0.8]},
                   {"type": "directional", "direction": [0.2, 1, 0.5], "colour": [0.3, 0.3, 0.3]}]
    })
}

fn renderer(doc: &Value) -> Renderer {
    Renderer::new(Arc::new(
        parse(&serde_json::to_vec(doc).unwrap(), &Limits::NONE).unwrap(),
    ))
}

#[test]
fn bvh_finds_the_same_hit_as_brute_force() {
    for seed in 1..=6 {
        let r = renderer(&random_scene(seed, 60, 64));
        let (w, h) = (r.scene.width, r.scene.height);
        let mut hits = 0;
        for v in 0..h {
            for u in 0..w {
                let ray = r.camera.pixel_centre(u, v);
                let fast = r.world.closest(&ray, 1e-9, f64::INFINITY);
                let slow = r.world.closest_brute_force(&ray, 1e-9, f64::INFINITY);
                assert_eq!(fast, slow, "seed {seed}, pixel ({u}, {v})");
                hits += fast.is_some() as u32;
            }
        }
        assert!(
            hits > w * h / 10,
            "seed {seed}: the scene should be seen ({hits} hits)"
        );
        // Secondary rays start anywhere and go anywhere.
        let mut rng = Rng(seed * 7919);
        for _ in 0..2000 {
            let ray = Ray::new(
                DVec3::from(rng.v3(-8.0, 8.0)) + DVec3::new(0.0, 0.0, 10.0),
                DVec3::from(rng.v3(-1.0, 1.0)),
            );
            assert_eq!(
                r.world.closest(&ray, 1e-9, f64::INFINITY),
                r.world.closest_brute_force(&ray, 1e-9, f64::INFINITY)
            );
            let shadow = r.world.occluded(&ray, 1e-9, 1.0);
            assert_eq!(
                shadow,
                r.world.closest_brute_force(&ray, 1e-9, 1.0).is_some()
            );
            // A hint, right or wrong, changes no answer; what it becomes blocks the ray.
            let n = r.world.len() as u32;
            let given = (rng.next() < 0.8).then(|| ((rng.next() * n as f64) as u32).min(n - 1));
            let mut hint = ShadowHint::new(given);
            assert_eq!(r.world.occluded_hinted(&ray, 1e-9, 1.0, &mut hint), shadow);
            match hint.object() {
                None => assert!(!shadow, "a blocked ray names its blocker"),
                Some(i) => {
                    let alone = r.world.intersect_object(i, &ray, 1e-9, 1.0, &mut ());
                    assert!(alone.is_some(), "hint {given:?} became {i}, which misses");
                    // Given back, the blocker is the answer again, and stays.
                    assert!(r.world.occluded_hinted(&ray, 1e-9, 1.0, &mut hint));
                    assert_eq!(hint.object(), Some(i));
                }
            }
        }
    }
}

/// A height field of `n × n` quads (two triangles each), bumpy, so that a packet's rays
/// part ways inside the mesh's own BVH.
fn height_field(n: u32) -> Value {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, z) = (
                i as f64 / n as f64 * 2.0 - 1.0,
                j as f64 / n as f64 * 2.0 - 1.0,
            );
            positions.push([x, 0.3 * (5.0 * x).sin() * (4.0 * z).cos(), z]);
        }
    }
    let mut indices = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i;
            indices.push([a, a + n + 1, a + 1]);
            indices.push([a + 1, a + n + 1, a + n + 2]);
        }
    }
    json!({
        "shape": "mesh", "positions": positions, "indices": indices,
        "material": {"diffuse": [0.5, 0.5, 0.5], "mirror": [0.2, 0.2, 0.2]},
        "transform": [{"scale": 6}, {"rotate": {"axis": "x", "degrees": -70}}, {"translate": [0, 0, 16]}]
    })
}

#[test]
fn packets_of_eight_rays_find_what_each_ray_finds_alone() {
    for seed in 31..=36 {
        // Seed 35 is the height field alone: a world of one object, which packets and
        // shadow rays go to without the world's tree. Seed 36 has four objects beside
        // it: a tree too small for the wide form, tested in double precision (a
        // packet's shadow rays prepared for it together, `SlabRays8`).
        let objects = match seed {
            35 => 0,
            36 => 4,
            _ => 40,
        };
        let mut doc = random_scene(seed, objects, 60);
        doc["objects"]
            .as_array_mut()
            .unwrap()
            .push(height_field(16));
        // Some take several samples a pixel: a packet a sample, and each pixel's mean
        // the one it has alone.
        doc["image"]["samples"] = json!(match seed {
            32 | 35 => 2,
            34 => 3,
            _ => 1,
        });
        let r = renderer(&doc);
        // Shadow rays go as packets through the height field alone, one at a time
        // through a tree of objects.
        assert_eq!(r.world.traces_shadow_packets(), seed == 35);
        let (w, h) = (r.scene.width, r.scene.height);
        let (mut hits, mut skipped) = (0, 0);
        // Packets by how many of their pixels' first hits send a secondary ray of each
        // branch (reflection, refraction): one lane alone, or two and more.
        let mut sending = [[0; 2]; 2];
        // Packets of both shapes: eight pixels of a row, and four of each of two rows.
        for rows in [1, 2] {
            for v in (0..h - (rows - 1)).step_by(rows as usize) {
                // One shader a pair of rows, as the renderer's: its shadow hints carry
                // from packet to packet and change no colour.
                let shader = r.shader();
                let cols = 8 / rows;
                for u in (0..w - (cols - 1)).step_by(cols as usize) {
                    let p = if rows == 1 {
                        Packet::row(u, v)
                    } else {
                        Packet::pair(u, v)
                    };
                    let pixels: Vec<_> = (0..8).map(|k| p.pixel(k)).collect();
                    let expected: Vec<_> = (0..rows)
                        .flat_map(|y| (0..cols).map(move |x| (u + x, v + y)))
                        .collect();
                    assert_eq!(
                        pixels, expected,
                        "lane k at (u + k mod cols, v + k div cols)"
                    );
                    let alone: Vec<_> = pixels.iter().map(|&(x, y)| r.pixel_hit(x, y)).collect();
                    // Packets whose rays all miss the objects' box test the planes alone.
                    let bounded = r.may_meet_objects(Rect {
                        x: u,
                        y: v,
                        width: cols,
                        height: rows,
                    });
                    skipped += usize::from(!bounded);
                    let (mut first, mut second) = (Vec::new(), Vec::new());
                    r.pixel_hits8(p, bounded, [&mut first, &mut second]);
                    assert_eq!(first.len() as u32, cols, "one row's pixels in the first");
                    let packet = [first, second].concat();
                    assert_eq!(packet, alone, "seed {seed} {p:?}");
                    hits += alone.iter().flatten().count();
                    for (branch, sends) in sending.iter_mut().enumerate() {
                        let lanes = alone
                            .iter()
                            .flatten()
                            .filter(|s| {
                                let object = &r.scene.objects[s.object as usize];
                                let m = &r.scene.materials[object.material as usize];
                                [m.mirror, m.transmission][branch] != DVec3::ZERO
                            })
                            .count();
                        if lanes > 0 {
                            sends[usize::from(lanes > 1)] += 1;
                        }
                    }
                    let mut n = raytile::render::RayCount(0);
                    let colours = r.pixel_colours8(&shader, p, bounded, &mut n);
                    let mut m = raytile::render::RayCount(0);
                    let one: Vec<_> = pixels
                        .iter()
                        .map(|&(x, y)| r.pixel_colour(x, y, &mut m))
                        .collect();
                    assert_eq!(colours.to_vec(), one, "seed {seed} {p:?}");
                    assert_eq!(n.0, m.0, "the same rays are counted");
                }
            }
        }
        assert!(
            hits > (2 * w * h / 10) as usize,
            "seed {seed}: only {hits} hits"
        );
        // Secondary rays are traced as packets, or alone where one lane sends one.
        if seed != 35 {
            assert!(
                sending.iter().flatten().all(|&n| n > 0),
                "seed {seed}: packets sending one and several secondary rays of each \
                 branch: {sending:?}"
            );
        }
        // Around the height field alone there is sky: packets there test no object.
        assert!(seed != 35 || skipped > 0, "no packet skipped the objects");
        // Eight unrelated rays at a time: a packet that parts at once.
        let mut rng = Rng(seed * 104_729);
        for _ in 0..500 {
            let rays = [0; 8].map(|_| {
                Ray::new(
                    DVec3::from(rng.v3(-8.0, 8.0)) + DVec3::new(0.0, 0.0, 10.0),
                    DVec3::from(rng.v3(-1.0, 1.0)),
                )
            });
            let eight = r
                .world
                .closest8(&rays, false, 0xff, 1e-9, f64::INFINITY, true);
            for (k, ray) in rays.iter().enumerate() {
                assert_eq!(
                    eight[k],
                    r.world.closest_brute_force(ray, 1e-9, f64::INFINITY)
                );
                assert_eq!(
                    r.world.occluded(ray, 1e-9, 2.0),
                    r.world.closest_brute_force(ray, 1e-9, 2.0).is_some()
                );
            }
            // The same directions from the viewpoint: told so (each object's rays from
            // the viewpoint's origin in its space) or not (each ray's origin carried),
            // the same hits.
            let from_view = rays.map(|ray| Ray::new(r.camera.origin(), ray.dir));
            let told = r
                .world
                .closest8(&from_view, true, 0xff, 1e-9, f64::INFINITY, true);
            let untold = r
                .world
                .closest8(&from_view, false, 0xff, 1e-9, f64::INFINITY, true);
            assert_eq!(told, untold, "seed {seed}");
            for (k, ray) in from_view.iter().enumerate() {
                assert_eq!(
                    told[k],
                    r.world.closest_brute_force(ray, 1e-9, f64::INFINITY)
                );
            }
            // A ray along an axis plane is too much for the packet's f32 test: the eight
            // are traced one at a time, with the same answers.
            let mut flat = rays;
            flat[2 + 4 * (rng.0 as usize % 2)].dir.y = 0.0;
            let eight = r
                .world
                .closest8(&flat, false, 0xff, 1e-9, f64::INFINITY, true);
            for (k, ray) in flat.iter().enumerate() {
                assert_eq!(
                    eight[k],
                    r.world.closest_brute_force(ray, 1e-9, f64::INFINITY)
                );
            }
            // The same rays as shadow rays, some lanes asked, each to its own reach.
            let active = (rng.0 % 255 + 1) as u32;
            let reach = [0; 8].map(|_| match rng.next() {
                x if x < 0.3 => f64::INFINITY,
                x => 30.0 * x,
            });
            for packet in [rays, flat] {
                let blocked = r
                    .world
                    .occluded8(&Rays8::from_rays(&packet), active, 1e-9, &reach);
                for (k, ray) in packet.iter().enumerate() {
                    let alone = active >> k & 1 == 1 && r.world.occluded(ray, 1e-9, reach[k]);
                    assert_eq!(blocked >> k & 1 == 1, alone, "seed {seed} lane {k}");
                }
                // One after another with a hint carried from each to the next (a lone
                // ray's test, inlined into one loop), the same answers, and the hint
                // left is the one the lone tests leave.
                let given = ShadowHint::new(Some(rng.0 as u32 % r.world.len() as u32));
                let lanes = Rays8::from_rays(&packet);
                let (mut carried, mut each) = (given, given);
                let in_turn = r
                    .world
                    .occluded_each(&lanes, active, 1e-9, &reach, &mut carried);
                for (k, ray) in packet.iter().enumerate() {
                    let alone = active >> k & 1 == 1
                        && r.world.occluded_hinted(ray, 1e-9, reach[k], &mut each);
                    assert_eq!(in_turn >> k & 1 == 1, alone, "seed {seed} lane {k}");
                }
                assert_eq!(carried, each, "seed {seed}");
                // A lane at a time, the hint each ray leaves (the first plane that blocks
                // it, the object the tree finds) is the lone test's.
                let (mut carried, mut each) = (given, given);
                for k in 0..8 {
                    let alone = r
                        .world
                        .occluded_hinted(&packet[k], 1e-9, reach[k], &mut each);
                    let lane = r
                        .world
                        .occluded_each(&lanes, 1 << k, 1e-9, &reach, &mut carried);
                    assert_eq!(
                        (lane == 1 << k, carried),
                        (alone, each),
                        "seed {seed} lane {k}"
                    );
                }
                // And as secondary rays of some pixels: the lanes asked find what they
                // find alone, the others nothing.
                let found = r
                    .world
                    .closest8(&packet, false, active, 1e-9, f64::INFINITY, true);
                for (k, ray) in packet.iter().enumerate() {
                    let alone = (active >> k & 1 == 1)
                        .then(|| r.world.closest(ray, 1e-9, f64::INFINITY))
                        .flatten();
                    assert_eq!(found[k], alone, "seed {seed} lane {k}");
                }
            }
        }
    }
}

/// The scene with `steps` appended to the camera's and every object's transform, so the
/// common move applies after each one's own placement.
fn moved(doc: &Value, steps: &Value) -> Value {
    let mut d = doc.clone();
    let append = |list: &mut Value| {
        let mut l = list.as_array().cloned().unwrap_or_default();
        l.extend(steps.as_array().unwrap().iter().cloned());
        *list = Value::Array(l);
    };
    for o in d["objects"].as_array_mut().unwrap() {
        if o.get("transform").is_none() {
            o["transform"] = json!([]);
        }
        append(&mut o["transform"]);
    }
    if d["camera"].get("transform").is_none() {
        d["camera"]["transform"] = json!([]);
    }
    append(&mut d["camera"]["transform"]);
    d
}

#[test]
fn moving_camera_and_objects_together_changes_nothing() {
    let steps = json!([{"rotate": {"axis": [1, 2, 3], "degrees": 37}}, {"translate": [3, -2, 7]}]);
    for seed in [11, 12, 13] {
        let mut doc = random_scene(seed, 30, 48);
        doc["lights"] = json!([]); // Lights would have to move too; geometry is the point here.
        let a = renderer(&doc);
        let b = renderer(&moved(&doc, &steps));
        for v in 0..a.scene.height {
            for u in 0..a.scene.width {
                match (a.pixel_hit(u, v), b.pixel_hit(u, v)) {
                    (None, None) => {}
                    (Some(x), Some(y)) => {
                        assert_eq!(x.object, y.object, "seed {seed}, pixel ({u}, {v})");
                        // The same λ up to the rounding of the extra transform.
                        assert!(
                            (x.lambda - y.lambda).abs() <= 1e-9 * x.lambda,
                            "seed {seed} ({u}, {v}): {} vs {}",
                            x.lambda,
                            y.lambda
                        );
                        assert!((x.object_point - y.object_point).length() < 1e-9);
                    }
                    (x, y) => panic!("seed {seed}, pixel ({u}, {v}): {x:?} vs {y:?}"),
                }
            }
        }
    }
}

#[test]
fn output_is_identical_whatever_the_tiles_and_threads() {
    let dir = tempfile::tempdir().unwrap();
    // Primary rays go in packets of eight (with two samples a pixel, one packet a
    // sample); a tile 7 wide traces each row one pixel at a time, one 13 wide ends each
    // row with five pixels traced alone.
    for samples in [1, 2] {
        let mut doc = random_scene(21, 40, 120);
        doc["image"]["samples"] = json!(samples);
        doc["image"]["gamma"] = json!(2.2);
        let scene = scene_file(&dir, &format!("s{samples}.json"), &doc);
        same_output_for_every_tiling(&dir, &scene, samples);
    }
}

/// Renders and writes the hit data of `scene` with 1 and 2 threads and several tile
/// sizes, and checks that every output is byte for byte the first one.
fn same_output_for_every_tiling(dir: &tempfile::TempDir, scene: &std::path::Path, samples: u32) {
    let mut first: Option<(Vec<u8>, Vec<u8>, Vec<u8>)> = None;
    for threads in ["1", "2"] {
        for tile in ["8", "7", "13", "32", "64"] {
            let outs: Vec<Vec<u8>> = ["png", "json", "npy"]
                .iter()
                .map(|ext| {
                    let cmd = if *ext == "png" { "render" } else { "hits" };
                    let out = dir
                        .path()
                        .join(format!("o-{samples}-{threads}-{tile}.{ext}"));
                    let res = run(&[
                        cmd,
                        scene.to_str().unwrap(),
                        "-o",
                        out.to_str().unwrap(),
                        "--threads",
                        threads,
                        "--tile",
                        tile,
                    ]);
                    assert!(
                        res.status.success(),
                        "{}",
                        String::from_utf8_lossy(&res.stderr)
                    );
                    std::fs::read(out).unwrap()
                })
                .collect();
            let got = (outs[0].clone(), outs[1].clone(), outs[2].clone());
            match &first {
                None => first = Some(got),
                Some(f) => assert!(
                    f == &got,
                    "{samples} samples: threads {threads}, tile {tile} differ from threads 1, tile 8"
                ),
            }
        }
    }
}

#[test]
fn a_region_has_exactly_the_pixels_of_the_full_render() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene_file(&dir, "s.json", &random_scene(5, 30, 96));
    let full = dir.path().join("full.png");
    let part = dir.path().join("part.png");
    assert!(
        run(&[
            "render",
            scene.to_str().unwrap(),
            "-o",
            full.to_str().unwrap()
        ])
        .status
        .success()
    );
    assert!(
        run(&[
            "render",
            scene.to_str().unwrap(),
            "-o",
            part.to_str().unwrap(),
            "--region",
            "13,7,50,41",
            "--tile",
            "16"
        ])
        .status
        .success()
    );
    let (fw, _, fb) = decode_png(&std::fs::read(full).unwrap());
    let (pw, ph, pb) = decode_png(&std::fs::read(part).unwrap());
    assert_eq!((pw, ph), (50, 41));
    for y in 0..41usize {
        let src = ((7 + y) * fw as usize + 13) * 3;
        assert_eq!(&pb[y * 150..(y + 1) * 150], &fb[src..src + 150], "row {y}");
    }
}
