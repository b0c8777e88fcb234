//! An explanation as text, laid out like the lecture's worked example ([`to_text`]):
//! numbers as the lecture writes them, matrices in aligned columns, and the ray tree
//! indented by depth.

use std::fmt::Write as _;

use super::model::{Explanation, ObjectTest, Ray4, RayNode, Role, Truncation};

impl Role {
    /// How the text names a ray's role.
    fn label(self) -> &'static str {
        match self {
            Role::Primary => "primary",
            Role::Reflected => "reflected",
            Role::Refracted => "refracted",
            Role::TotalInternalReflection => "refracted (total internal reflection)",
        }
    }
}

/// A number as the lecture writes it: integers without a decimal point, others in
/// their shortest round-trip form (so the digits are exactly the computed ones).
fn num(x: f64) -> String {
    if x == 0.0 {
        // −0 and 0 are the same number; the lecture writes 0.
        "0".into()
    } else if x.is_infinite() {
        if x > 0.0 {
            "∞".into()
        } else {
            "−∞".into()
        }
    } else if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{x:.0}")
    } else {
        format!("{x:?}")
    }
}

fn vec_text(v: &[f64]) -> String {
    let parts: Vec<String> = v.iter().map(|&x| num(x)).collect();
    format!("[{}]", parts.join(", "))
}

fn ray_text(r: &Ray4) -> String {
    format!("{} + λ {}", vec_text(&r.origin), vec_text(&r.direction))
}

fn matrix_text(m: &[[f64; 4]; 4], indent: &str, label: &str) -> String {
    let cells: Vec<Vec<String>> = m
        .iter()
        .map(|row| row.iter().map(|&x| num(x)).collect())
        .collect();
    // Each column as wide as its widest entry, as a matrix is written by hand.
    let widths: Vec<usize> = (0..4)
        .map(|j| {
            cells
                .iter()
                .map(|r| r[j].chars().count())
                .max()
                .unwrap_or(1)
        })
        .collect();
    let mut out = String::new();
    let pad = " ".repeat(label.chars().count());
    for (k, row) in cells.iter().enumerate() {
        let body: Vec<String> = row
            .iter()
            .zip(&widths)
            .map(|(s, &w)| format!("{s:>w$}"))
            .collect();
        let lead = if k == 0 { label } else { &pad };
        let _ = writeln!(out, "{indent}{lead}[ {} ]", body.join("  "));
    }
    out
}

fn name_text(object: u32, name: &Option<String>) -> String {
    match name {
        Some(n) => format!("object {object} \"{n}\""),
        None => format!("object {object}"),
    }
}

/// The explanation as text, laid out like the lecture's worked example.
pub fn to_text(e: &Explanation) -> String {
    let mut o = String::new();
    let i = &e.image;
    let _ = writeln!(
        o,
        "Pixel ({}, {}) of a {} × {} image (focal length f = {}, {}, max_depth {})",
        e.u,
        e.v,
        i.width,
        i.height,
        num(i.focal_length),
        crate::scene::sample_grid(i.samples),
        i.max_depth
    );
    direction_text(e, &mut o);
    let p = &e.primary;
    let _ = writeln!(o, "  camera space: p(λ) = {}", ray_text(&p.camera));
    if p.camera == p.world {
        let _ = writeln!(
            o,
            "  world space:  p(λ) = {} (the camera is at the origin)",
            ray_text(&p.world)
        );
    } else {
        o.push_str(&matrix_text(
            &p.world_from_camera,
            "  ",
            "camera → world = ",
        ));
        let _ = writeln!(o, "  world space:  p(λ) = {}", ray_text(&p.world));
    }
    node_text(&mut o, &e.tree, "", &mut 1, &e.truncation);

    let c = &e.colour;
    let _ = writeln!(o, "\nFinal colour");
    if !c.samples.is_empty() {
        let _ = writeln!(o, "  centre ray:   {}", vec_text(&c.centre_linear));
        for s in &c.samples {
            let _ = writeln!(
                o,
                "  sample at ({}, {}): {}",
                num(s.image_point[0]),
                num(s.image_point[1]),
                vec_text(&s.linear)
            );
        }
        let _ = writeln!(o, "  mean (linear): {}", vec_text(&c.linear));
    } else {
        let _ = writeln!(o, "  linear:       {}", vec_text(&c.linear));
    }
    if let Some(g) = c.gamma {
        let _ = writeln!(o, "  c^(1/{}):     {}", num(g), vec_text(&c.encoded));
    }
    let _ = writeln!(
        o,
        "  8-bit:        round(255 · clamp(c, 0, 1)) = [{}, {}, {}]  {}",
        c.rgb8[0], c.rgb8[1], c.rgb8[2], c.hex
    );
    if e.truncated {
        let t = &e.truncation;
        let _ = writeln!(
            o,
            "\nShortened to stay readable: {} rays not broken down; {} object tests, {} \
             triangle tests and {} lights not listed{}",
            t.rays_not_broken_down,
            t.tests_unlisted,
            t.triangles_unlisted,
            t.lights_unlisted,
            match &t.budget_spent_at {
                Some(a) => format!(
                    "; the size budget of {} bytes ran out at Ray {}",
                    t.max_bytes, a.ray
                ),
                None => String::new(),
            }
        );
    }
    if !e.notes.is_empty() {
        let _ = writeln!(o, "\nNotes");
        for n in &e.notes {
            let _ = writeln!(o, "  - {n}");
        }
    }
    o
}

/// The primary direction `d` step by step, as the lecture works it out: the formula, the
/// numbers put in, each term ([`super::model::DirectionTerms`]), and the direction the
/// tracer uses.
fn direction_text(e: &Explanation, o: &mut String) {
    let p = &e.primary;
    let t = &p.direction_terms;
    let (x, y) = (p.image_point[0], p.image_point[1]);
    let (w, h, f) = (
        f64::from(e.image.width),
        f64::from(e.image.height),
        e.image.focal_length,
    );
    let _ = writeln!(
        o,
        "\nPrimary ray through the image point (x, y) = ({}, {}) (pixel ({}, {}) + ½):",
        num(x),
        num(y),
        e.u,
        e.v
    );
    let _ = writeln!(o, "  d = [-1 + x·2/w, -h/w + y·2/w, f, 0]");
    let _ = writeln!(
        o,
        "    = [-1 + {x}·2/{w}, -{h}/{w} + {y}·2/{w}, {f}, 0]",
        x = num(x),
        y = num(y),
        w = num(w),
        h = num(h),
        f = num(f)
    );
    let _ = writeln!(
        o,
        "    = [-1 + {}, -{} + {}, {}, 0]",
        num(t.x_term),
        num(t.aspect),
        num(t.y_term),
        num(f)
    );
    let _ = writeln!(o, "    = {}", vec_text(&p.camera.direction));
}

/// For a tangent hit (the ray grazes the surface, `n · d = 0`), why the shading normal
/// is the negated one: the rule that turns `n` to face the ray counts the tie as "not
/// from the outside".
fn tangent_text(o: &mut String, ind: &str, n: &RayNode, h: &super::model::HitInfo) {
    let d = &n.ray.direction;
    let dot: f64 = (0..3).map(|k| h.normal[k] * d[k]).sum();
    let scale = (0..3).map(|k| d[k] * d[k]).sum::<f64>().sqrt();
    if h.front || dot.abs() > 1e-12 * scale.max(f64::MIN_POSITIVE) {
        return;
    }
    let turned = match &n.shading {
        Some(s) => vec_text(&s.n),
        None => vec_text(&[-h.normal[0], -h.normal[1], -h.normal[2]]),
    };
    let _ = writeln!(
        o,
        "{ind}    a tangent: the ray grazes the surface, n · d = 0, so it arrives from neither side."
    );
    let _ = writeln!(
        o,
        "{ind}    Shading turns n to face the ray whenever n · d ≥ 0, and the tie counts: the"
    );
    let _ = writeln!(
        o,
        "{ind}    shading normal is −n = {turned}, and secondary rays leave on that side."
    );
}

/// Writes ray number `*counter` and, numbering on, the rays below it.
fn node_text(o: &mut String, n: &RayNode, ind: &str, counter: &mut usize, cut: &Truncation) {
    let number = *counter;
    let _ = writeln!(
        o,
        "\n{ind}Ray {number}: {} ray, depth {}: p(λ) = {}",
        n.role.label(),
        n.depth,
        ray_text(&n.ray)
    );
    // The size budget, once spent, cuts every ray traced after the one it ran out at.
    let budget_spent = cut.budget_spent_at.as_ref().is_some_and(|a| number > a.ray);
    if n.truncated {
        let why = if budget_spent {
            format!(
                "the answer's size budget of {} bytes is spent",
                cut.max_bytes
            )
        } else {
            "the ray budget is spent".to_owned()
        };
        let _ = writeln!(
            o,
            "{ind}  (not broken down: {why}) colour {}",
            vec_text(&n.colour)
        );
        return;
    }
    let _ = writeln!(
        o,
        "{ind}  hits count for λ > {}; tested against {} of {} objects",
        num(n.lambda_min),
        n.tested,
        n.objects
    );
    for t in &n.tests {
        object_text(o, t, &format!("{ind}  "));
    }
    if n.tests_unlisted > 0 {
        let why = if n.tests.len() >= cut.max_tests {
            format!("at most {} are listed per ray", cut.max_tests)
        } else {
            format!(
                "the answer's size budget of {} bytes ran out",
                cut.max_bytes
            )
        };
        let _ = writeln!(
            o,
            "{ind}  … {} more objects tested, not listed: {why}",
            n.tests_unlisted
        );
    }
    let Some(h) = &n.hit else {
        let _ = writeln!(o, "{ind}  No hit: the background {}", vec_text(&n.colour));
        return;
    };
    let part = if h.part == h.shape {
        String::new()
    } else {
        format!(", {}", h.part)
    };
    let _ = writeln!(
        o,
        "{ind}  Hit: {} ({}{part}) at λ = {}",
        name_text(h.object, &h.name),
        h.shape,
        num(h.lambda)
    );
    let _ = writeln!(
        o,
        "{ind}    object-space point {}",
        vec_text(&h.object_point)
    );
    let _ = writeln!(o, "{ind}    world point        {}", vec_text(&h.point));
    let _ = writeln!(
        o,
        "{ind}    normal             {} ({})",
        vec_text(&h.normal),
        if h.front {
            "the ray arrives from its outside"
        } else {
            "the ray does not arrive from its outside: n · d ≥ 0"
        }
    );
    tangent_text(o, ind, n, h);
    let Some(s) = &n.shading else { return };
    let m = &s.material;
    let _ = writeln!(
        o,
        "{ind}  Shading: n = {}, v = {}",
        vec_text(&s.n),
        vec_text(&s.v)
    );
    let _ = writeln!(
        o,
        "{ind}    material: ambient {}, diffuse {}, specular {}, shininess {}, mirror {}, transmission {}, ior {}",
        vec_text(&m.ambient),
        vec_text(&m.diffuse),
        vec_text(&m.specular),
        num(m.shininess),
        vec_text(&m.mirror),
        vec_text(&m.transmission),
        num(m.ior)
    );
    let _ = writeln!(o, "{ind}    ambient ⊙ m.ambient = {}", vec_text(&s.ambient));
    for l in &s.lights {
        let _ = writeln!(
            o,
            "{ind}    light {} ({}, colour {}): shadow ray {} for λ in ({}, {})",
            l.light,
            l.kind,
            vec_text(&l.colour),
            ray_text(&l.shadow_ray),
            num(l.lambda_min),
            l.lambda_max.map_or("∞".into(), num)
        );
        if l.outside_cone {
            let _ = writeln!(o, "{ind}      outside the spot's cone: no light");
        } else if l.blocked {
            match &l.blocker {
                Some(b) => {
                    let _ = writeln!(
                        o,
                        "{ind}      blocked by {} at λ = {}: no diffuse or specular",
                        name_text(b.object, &b.name),
                        num(b.lambda)
                    );
                }
                None => {
                    let _ = writeln!(o, "{ind}      blocked: no diffuse or specular");
                }
            }
        } else {
            let _ = writeln!(
                o,
                "{ind}      not blocked: l = {}, n·l = {}, r·v = {}",
                vec_text(&l.l),
                num(l.n_dot_l),
                num(l.r_dot_v)
            );
            let _ = writeln!(
                o,
                "{ind}      diffuse {}, specular {}",
                vec_text(&l.diffuse),
                vec_text(&l.specular)
            );
        }
    }
    if s.lights_unlisted > 0 {
        let _ = writeln!(
            o,
            "{ind}    … {} more lights, not listed (their terms are in the colour all the same)",
            s.lights_unlisted
        );
    }
    if let Some(why) = &s.no_secondary {
        let _ = writeln!(o, "{ind}    no reflected or refracted ray: {why}");
    }
    let child_ind = format!("{ind}    ");
    for (label, sec) in [("mirror", &s.reflection), ("transmission", &s.refraction)] {
        if let Some(sec) = sec {
            *counter += 1;
            node_text(o, &sec.ray, &child_ind, counter, cut);
            let _ = writeln!(
                o,
                "{child_ind}  contribution: {label} {} ⊙ {} = {}",
                vec_text(&sec.coefficient),
                vec_text(&sec.ray.colour),
                vec_text(&sec.contribution)
            );
        }
    }
    let _ = writeln!(o, "{ind}  colour of this ray: {}", vec_text(&n.colour));
}

fn object_text(o: &mut String, t: &ObjectTest, ind: &str) {
    let _ = writeln!(o, "{ind}{} ({})", name_text(t.object, &t.name), t.shape);
    o.push_str(&matrix_text(
        &t.inverse_transform,
        &format!("{ind}  "),
        "T⁻¹ = ",
    ));
    let _ = writeln!(o, "{ind}  ray in object space: {}", ray_text(&t.object_ray));
    if t.linear_side {
        let _ = writeln!(
            o,
            "{ind}  side: a = 0 (parallel to a generator line), the equation is linear"
        );
    }
    for q in &t.quadratics {
        let _ = writeln!(
            o,
            "{ind}  {}: a = {}, b = {}, c = {}; discriminant b² − 4ac = {}",
            q.surface,
            num(q.a),
            num(q.b),
            num(q.c),
            num(q.discriminant)
        );
        let verdict = if q.discriminant < 0.0 {
            "negative: no real root, a miss"
        } else if q.roots.len() == 1 {
            "zero: one root, a tangent"
        } else if q.roots.is_empty() {
            "a = 0: no quadratic to solve"
        } else {
            "positive: two roots"
        };
        let _ = writeln!(o, "{ind}    discriminant {verdict}");
        for r in &q.roots {
            let _ = writeln!(
                o,
                "{ind}    λ = {} at {}: {}",
                num(r.lambda),
                vec_text(&r.point),
                r.why
            );
        }
    }
    for f in &t.faces {
        let face = match f.face {
            "top" | "bottom" => format!("{} cap", f.face),
            l if l.starts_with(['+', '-']) => format!("face {l}"),
            l => l.to_owned(),
        };
        match (f.lambda, f.point) {
            (Some(l), Some(p)) => {
                let _ = writeln!(
                    o,
                    "{ind}  {face}: λ = {}, point {}: {}",
                    num(l),
                    vec_text(&p),
                    f.why
                );
            }
            _ => {
                let _ = writeln!(o, "{ind}  {face}: {}", f.why);
            }
        }
    }
    for tr in &t.triangles {
        match (tr.barycentric, tr.lambda) {
            (Some([a, b]), Some(l)) => {
                let _ = writeln!(
                    o,
                    "{ind}  triangle {}: u = {}, v = {}, λ = {}: {}",
                    tr.triangle,
                    num(a),
                    num(b),
                    num(l),
                    tr.why
                );
            }
            _ => {
                let _ = writeln!(o, "{ind}  triangle {}: {}", tr.triangle, tr.why);
            }
        }
    }
    if t.triangles_unlisted > 0 {
        let _ = writeln!(
            o,
            "{ind}  … {} more triangle tests, none the first hit",
            t.triangles_unlisted
        );
    }
    if matches!(t.shape, "mesh") && t.triangles.is_empty() {
        let _ = writeln!(
            o,
            "{ind}  no triangle tested: the ray misses the mesh's bounding boxes"
        );
    }
    match (t.lambda, &t.part) {
        (Some(l), Some(part)) => {
            let _ = writeln!(
                o,
                "{ind}  → first hit λ = {} ({part}){}",
                num(l),
                if t.chosen { ", the ray's closest" } else { "" }
            );
        }
        _ => {
            let _ = writeln!(o, "{ind}  → no hit");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grade::explain::tests::renderer;
    use crate::grade::explain::{ExplainOptions, explain};

    #[test]
    fn lecture_text_shows_the_worked_example() {
        let r = renderer("lecture.json");
        let text = to_text(&explain(&r, 2, 2, &ExplainOptions::default()));
        for want in [
            "p(λ) = [0, 0, 0, 1] + λ [0, 0, 1, 0]",
            "T⁻¹ = [ 1  0  0  -1 ]",
            "      [ 0  0  1  -2 ]",
            "discriminant zero: one root, a tangent",
            "ray in object space: [-1, 0, -2, 1] + λ [0, 0, 1, 0]",
            "a = 1, b = -4, c = 4; discriminant b² − 4ac = 0",
            "λ = 2 at [-1, 0, 0, 1]: the object's first hit",
            "object-space point [-1, 0, 0, 1]",
        ] {
            assert!(text.contains(want), "missing {want:?} in\n{text}");
        }
    }

    #[test]
    fn the_primary_direction_is_worked_out_step_by_step() {
        let r = renderer("lecture.json");
        let text = to_text(&explain(&r, 2, 2, &ExplainOptions::default()));
        let want = "Primary ray through the image point (x, y) = (2.5, 2.5) (pixel (2, 2) + ½):
  d = [-1 + x·2/w, -h/w + y·2/w, f, 0]
    = [-1 + 2.5·2/5, -5/5 + 2.5·2/5, 1, 0]
    = [-1 + 1, -1 + 1, 1, 0]
    = [0, 0, 1, 0]
";
        assert!(text.contains(want), "missing {want:?} in\n{text}");
        // A corner pixel: the terms are not whole numbers. The JSON carries them too, and
        // they add up to the direction the tracer uses.
        let e = explain(&r, 0, 4, &ExplainOptions::default());
        let json = serde_json::to_value(&e).unwrap();
        assert_eq!(json["primary"]["direction_terms"]["x_term"], 0.2);
        assert_eq!(json["primary"]["direction_terms"]["aspect"], 1.0);
        let t = e.primary.direction_terms;
        let d = e.primary.camera.direction;
        assert_eq!((-1.0 + t.x_term, -t.aspect + t.y_term), (d[0], d[1]));
        let text = to_text(&e);
        assert!(
            text.contains("    = [-1 + 0.5·2/5, -5/5 + 4.5·2/5, 1, 0]\n    = [-1 + 0.2, -1 + 1.8, 1, 0]\n    = [-0.8, 0.8, 1, 0]\n"),
            "{text}"
        );
    }

    #[test]
    fn a_tangent_hit_says_why_the_shading_normal_is_turned() {
        let r = renderer("lecture.json");
        let text = to_text(&explain(&r, 2, 2, &ExplainOptions::default()));
        assert!(
            text.contains("a tangent: the ray grazes the surface, n · d = 0"),
            "{text}"
        );
        assert!(
            text.contains("the tie counts: the\n    shading normal is −n = [1, 0, 0]"),
            "{text}"
        );
        assert!(text.contains("1 sample per pixel,"), "{text}");
        // A hit that is not a tangent says nothing of the kind.
        let showcase = renderer("showcase.json");
        let text = to_text(&explain(&showcase, 512, 400, &ExplainOptions::default()));
        assert!(!text.contains("a tangent: the ray grazes"), "{text}");
        assert!(text.contains("2 × 2 samples per pixel"), "{text}");
    }

    #[test]
    fn numbers_print_as_the_lecture_writes_them() {
        assert_eq!(num(-0.0), "0");
        assert_eq!(num(2.0), "2");
        assert_eq!(num(-4.0), "-4");
        assert_eq!(num(0.1 + 0.2), "0.30000000000000004");
        assert_eq!(num(1e-9), "1e-9");
    }
}
