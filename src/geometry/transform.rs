//! Affine transforms between spaces, kept together with their inverses.
//!
//! A scene's `transform` list is applied in the listed order, so the first step acts
//! on the canonical shape first: `T = S_n · … · S_2 · S_1` (`docs/spec/transforms.md`). The inverse is
//! built from the inverses of the steps in reverse order (a rotation's inverse is its
//! transpose, a scale's is `1/s`), which keeps the lecture's simple cases exact: the
//! inverse of a translation by `(1, 0, 2)` is exactly a translation by `(−1, 0, −2)`.

use glam::{DAffine3, DMat3, DVec3};

/// An invertible affine map `to_from_from`, with its inverse.
///
/// Named target-from-source: `Transform::world_from_object` carries object-space points
/// into world space, `inverse` carries them back.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    /// The forward map.
    pub forward: DAffine3,
    /// Its inverse.
    pub inverse: DAffine3,
}

impl Default for Transform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Transform {
    /// The identity.
    pub const IDENTITY: Transform = Transform {
        forward: DAffine3::IDENTITY,
        inverse: DAffine3::IDENTITY,
    };

    /// A translation by `t`.
    pub fn translate(t: DVec3) -> Self {
        Self {
            forward: DAffine3::from_translation(t),
            inverse: DAffine3::from_translation(-t),
        }
    }

    /// A scaling about the origin; every factor must be non-zero.
    pub fn scale(s: DVec3) -> Self {
        Self {
            forward: DAffine3::from_scale(s),
            inverse: DAffine3::from_scale(DVec3::ONE / s),
        }
    }

    /// A rotation by `degrees` about the unit `axis`, right-hand rule (Rodrigues' formula).
    pub fn rotate(axis: DVec3, degrees: f64) -> Self {
        let (s, c) = sin_cos_degrees(degrees);
        let a = axis.normalize();
        let k = DMat3::from_cols(
            DVec3::new(0.0, a.z, -a.y),
            DVec3::new(-a.z, 0.0, a.x),
            DVec3::new(a.y, -a.x, 0.0),
        );
        let m = if a == DVec3::X || a == DVec3::Y || a == DVec3::Z {
            // Axis rotations are written out so that 90° gives exact zeros and ones.
            axis_rotation(a, s, c)
        } else {
            DMat3::IDENTITY + k * s + (k * k) * (1.0 - c)
        };
        Self {
            forward: DAffine3::from_mat3(m),
            inverse: DAffine3::from_mat3(m.transpose()),
        }
    }

    /// A general affine matrix, or `None` when it is singular.
    pub fn matrix(m: DAffine3) -> Option<Self> {
        let inverse = m.inverse();
        (m.matrix3.determinant() != 0.0 && inverse.is_finite()).then_some(Self {
            forward: m,
            inverse,
        })
    }

    /// `self` followed by `next`: the map `next ∘ self`.
    pub fn then(&self, next: &Transform) -> Transform {
        Transform {
            forward: next.forward * self.forward,
            inverse: self.inverse * next.inverse,
        }
    }

    /// The inverse map.
    pub fn inverted(&self) -> Transform {
        Transform {
            forward: self.inverse,
            inverse: self.forward,
        }
    }

    /// Whether every entry of both maps is finite.
    pub fn is_finite(&self) -> bool {
        self.forward.is_finite() && self.inverse.is_finite()
    }

    /// Carries a normal: `normalize((M⁻¹)ᵀ n)` with the 3 × 3 part (`docs/spec/shapes.md`, Normals).
    pub fn normal(&self, n: DVec3) -> DVec3 {
        self.inverse.matrix3.transpose().mul_vec3(n).normalize()
    }

    /// The forward map as a 4 × 4 matrix, rows first, as the lecture writes it.
    pub fn forward_rows(&self) -> [[f64; 4]; 4] {
        rows(&self.forward)
    }

    /// The inverse map as a 4 × 4 matrix, rows first.
    pub fn inverse_rows(&self) -> [[f64; 4]; 4] {
        rows(&self.inverse)
    }
}

/// Rows of the homogeneous 4 × 4 form of an affine map.
pub fn rows(m: &DAffine3) -> [[f64; 4]; 4] {
    let c = m.matrix3;
    let t = m.translation;
    [
        [c.x_axis.x, c.y_axis.x, c.z_axis.x, t.x],
        [c.x_axis.y, c.y_axis.y, c.z_axis.y, t.y],
        [c.x_axis.z, c.y_axis.z, c.z_axis.z, t.z],
        [0.0, 0.0, 0.0, 1.0],
    ]
}

/// `sin` and `cos` of an angle in degrees, exact at multiples of 90°.
fn sin_cos_degrees(degrees: f64) -> (f64, f64) {
    let turns = degrees.rem_euclid(360.0);
    if turns % 90.0 == 0.0 {
        match (turns / 90.0) as u8 {
            0 => (0.0, 1.0),
            1 => (1.0, 0.0),
            2 => (0.0, -1.0),
            _ => (-1.0, 0.0),
        }
    } else {
        degrees.to_radians().sin_cos()
    }
}

fn axis_rotation(a: DVec3, s: f64, c: f64) -> DMat3 {
    if a == DVec3::X {
        DMat3::from_cols(
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.0, c, s),
            DVec3::new(0.0, -s, c),
        )
    } else if a == DVec3::Y {
        DMat3::from_cols(
            DVec3::new(c, 0.0, -s),
            DVec3::new(0.0, 1.0, 0.0),
            DVec3::new(s, 0.0, c),
        )
    } else {
        DMat3::from_cols(
            DVec3::new(c, s, 0.0),
            DVec3::new(-s, c, 0.0),
            DVec3::new(0.0, 0.0, 1.0),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn translation_inverse_is_exact() {
        let t = Transform::translate(DVec3::new(1.0, 0.0, 2.0));
        assert_eq!(
            t.inverse.transform_point3(DVec3::ZERO),
            DVec3::new(-1.0, 0.0, -2.0)
        );
        assert_eq!(
            t.inverse_rows(),
            [
                [1.0, 0.0, 0.0, -1.0],
                [0.0, 1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0, -2.0],
                [0.0, 0.0, 0.0, 1.0]
            ]
        );
    }

    #[test]
    fn steps_apply_in_listed_order() {
        // scale 2 then translate: a unit point lands at 2 + t, not 1 + 2t.
        let t = Transform::scale(DVec3::splat(2.0))
            .then(&Transform::translate(DVec3::new(1.0, 0.0, 2.0)));
        assert_eq!(
            t.forward.transform_point3(DVec3::X),
            DVec3::new(3.0, 0.0, 2.0)
        );
        assert_eq!(
            t.inverse.transform_point3(DVec3::new(3.0, 0.0, 2.0)),
            DVec3::X
        );
    }

    #[test]
    fn right_hand_rotation_about_axes() {
        let rz = Transform::rotate(DVec3::Z, 90.0);
        assert_eq!(rz.forward.transform_vector3(DVec3::X), DVec3::Y);
        let rx = Transform::rotate(DVec3::X, 90.0);
        assert_eq!(rx.forward.transform_vector3(DVec3::Y), DVec3::Z);
        let ry = Transform::rotate(DVec3::Y, 90.0);
        assert_eq!(ry.forward.transform_vector3(DVec3::Z), DVec3::X);
    }

    #[test]
    fn general_axis_matches_axis_formula() {
        let a = Transform::rotate(DVec3::new(0.0, 2.0, 0.0), 30.0);
        let b = Transform::rotate(DVec3::Y, 30.0);
        assert!(a.forward.abs_diff_eq(b.forward, 1e-15));
    }

    #[test]
    fn normals_use_inverse_transpose() {
        // A sphere squashed along y: the normal at 45° tilts toward y.
        let t = Transform::scale(DVec3::new(1.0, 0.5, 1.0));
        let n = t.normal(DVec3::new(1.0, 1.0, 0.0).normalize());
        let expect = DVec3::new(1.0, 2.0, 0.0).normalize();
        assert!((n - expect).length() < 1e-15);
    }

    #[test]
    fn singular_matrix_is_refused() {
        let m = DAffine3::from_scale(DVec3::new(1.0, 0.0, 1.0));
        assert!(Transform::matrix(m).is_none());
    }
}
