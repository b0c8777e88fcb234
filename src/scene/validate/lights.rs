//! `lights`: non-negative colours, non-zero directions, and a spot's half-angle in
//! (0, 180] degrees (see `docs/spec/shading.md#lights`).
//!
//! ```json
//! "lights": [ { "type": "point", "position": [2, 4, 3], "colour": [1, 1, 1] },
//!             { "type": "spot", "position": [0, 4, 0], "direction": [0, -1, 0],
//!               "angle_degrees": 30, "color": [1, 1, 1] } ]
//! ```

use std::collections::HashSet;

use glam::DVec3;

use super::{Problems, colour, unit, vec3};
use crate::scene::Light;
use crate::scene::document::LightDoc;
use crate::scene::problem::Pointer;

/// Checks `lights` (at `at`), skipping those that could not be read (`unreadable`),
/// and returns those that passed, in document order.
pub(super) fn check(
    docs: &[LightDoc],
    unreadable: &HashSet<usize>,
    at: &Pointer,
    p: &mut Problems,
) -> Vec<Light> {
    docs.iter()
        .enumerate()
        .filter(|(i, _)| !unreadable.contains(i))
        .filter_map(|(i, l)| light(l, &at.index(i), p))
        .collect()
}

fn light(l: &LightDoc, at: &Pointer, p: &mut Problems) -> Option<Light> {
    let before = p.list.len() + p.dropped;
    let out = match l {
        LightDoc::Point {
            position,
            colour: c,
        } => Light::Point {
            position: vec3(*position),
            colour: colour(Some(*c), [0.0; 3], &at.key("colour"), p),
        },
        LightDoc::Directional {
            direction,
            colour: c,
        } => {
            let direction = unit(vec3(*direction));
            if direction.is_none() {
                p.add(&at.key("direction"), "the direction has zero length");
            }
            Light::Directional {
                direction: direction.unwrap_or(DVec3::Y),
                colour: colour(Some(*c), [0.0; 3], &at.key("colour"), p),
            }
        }
        LightDoc::Spot {
            position,
            direction,
            angle_degrees,
            colour: c,
        } => {
            let direction = unit(vec3(*direction));
            if direction.is_none() {
                p.add(&at.key("direction"), "the direction has zero length");
            }
            if !(*angle_degrees > 0.0 && *angle_degrees <= 180.0) {
                p.add(
                    &at.key("angle_degrees"),
                    "the half-angle must be in (0, 180]",
                );
            }
            Light::Spot {
                position: vec3(*position),
                direction: direction.unwrap_or(DVec3::Y),
                cos_angle: angle_degrees.to_radians().cos(),
                colour: colour(Some(*c), [0.0; 3], &at.key("colour"), p),
            }
        }
    };
    (p.list.len() + p.dropped == before).then_some(out)
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn lights(v: serde_json::Value) -> (Vec<Light>, Vec<(String, String)>) {
        let docs: Vec<LightDoc> = serde_json::from_value(v).expect("lights");
        let mut p = Problems::default();
        let out = check(
            &docs,
            &HashSet::new(),
            &Pointer::root().key("lights"),
            &mut p,
        );
        (out, p.pairs())
    }

    fn one(pointer: &str, message: &str) -> Vec<(String, String)> {
        vec![(pointer.into(), message.into())]
    }

    #[test]
    fn good_lights_have_no_problem_and_unit_directions() {
        let (out, found) = lights(json!([
            {"type": "point", "position": [1, 2, 3], "colour": [1, 1, 1]},
            {"type": "directional", "direction": [0, -4, 0], "color": [0.5, 0.5, 0.5]},
            {"type": "spot", "position": [0, 4, 0], "direction": [0, 0, 2], "angle_degrees": 180, "colour": [0, 0, 0]}
        ]));
        assert_eq!(found, []);
        assert_eq!(
            out[0],
            Light::Point {
                position: DVec3::new(1.0, 2.0, 3.0),
                colour: DVec3::ONE
            }
        );
        assert_eq!(
            out[1],
            Light::Directional {
                direction: DVec3::NEG_Y,
                colour: DVec3::splat(0.5)
            }
        );
        let Light::Spot {
            direction,
            cos_angle,
            ..
        } = out[2]
        else {
            panic!("a spot light, got {:?}", out[2])
        };
        assert_eq!(direction, DVec3::Z);
        assert_eq!(cos_angle, -1.0);
    }

    #[test]
    fn a_negative_colour_channel_is_reported_at_its_index() {
        assert_eq!(
            lights(json!([{"type": "point", "position": [0, 0, 0], "colour": [1, -0.25, 1]}])),
            (
                vec![],
                one("/lights/0/colour/1", "colours cannot be negative (-0.25)")
            )
        );
    }

    #[test]
    fn a_zero_direction_is_refused_for_directional_and_spot_lights() {
        let (out, found) = lights(json!([
            {"type": "directional", "direction": [0, 0, 0], "colour": [1, 1, 1]},
            {"type": "spot", "position": [0, 0, 0], "direction": [0, 0, 0], "angle_degrees": 30, "colour": [1, 1, 1]}
        ]));
        assert!(out.is_empty());
        assert_eq!(
            found,
            [
                (
                    "/lights/0/direction".into(),
                    "the direction has zero length".into()
                ),
                (
                    "/lights/1/direction".into(),
                    "the direction has zero length".into()
                ),
            ]
        );
    }

    #[test]
    fn a_spot_half_angle_must_be_in_0_to_180() {
        for angle in [0.0, -10.0, 180.5] {
            assert_eq!(
                lights(json!([{"type": "spot", "position": [0, 0, 0], "direction": [0, -1, 0], "angle_degrees": angle, "colour": [1, 1, 1]}])).1,
                one("/lights/0/angle_degrees", "the half-angle must be in (0, 180]"),
                "angle {angle}"
            );
        }
    }

    #[test]
    fn only_the_bad_light_is_dropped() {
        let (out, found) = lights(json!([
            {"type": "point", "position": [0, 0, 0], "colour": [-1, 0, 0]},
            {"type": "point", "position": [0, 0, 0], "colour": [1, 0, 0]}
        ]));
        assert_eq!(found.len(), 1);
        assert_eq!(out.len(), 1);
    }

    #[test]
    fn lights_that_could_not_be_read_are_skipped() {
        let docs: Vec<LightDoc> = serde_json::from_value(json!([
            {"type": "directional", "direction": [0, 0, 0], "colour": [1, 1, 1]},
            {"type": "point", "position": [0, 0, 0], "colour": [1, 1, 1]}
        ]))
        .expect("lights");
        let mut p = Problems::default();
        let out = check(
            &docs,
            &HashSet::from([0]),
            &Pointer::root().key("lights"),
            &mut p,
        );
        assert_eq!(p.pairs(), []);
        assert_eq!(out.len(), 1);
    }
}
