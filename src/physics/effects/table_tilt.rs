//! A tilted table: tilted by `angle` (rad) with its downhill direction at `azimuth` (rad, from the
//! ground plane's first tangent, +x for a horizontal table). Gravity gains an in-plane part for
//! every dynamic object. The diagnosis finds a tilt as a constant force (`constant_force`, whose
//! report gives the equivalent tilt).

use super::{Bound, Forces, Term};
use glam::Vec3;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TableTilt {
    pub angle: f32,
    pub azimuth: f32,
}

impl Term for TableTilt {
    fn parameters(&self) -> Vec<(&'static str, f32)> {
        vec![("angle", self.angle), ("azimuth", self.azimuth)]
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        match name {
            "angle" => Some(&mut self.angle),
            "azimuth" => Some(&mut self.azimuth),
            _ => None,
        }
    }

    fn accelerate(&self, at: &Forces, bound: &Bound, accel: &mut [Vec3]) {
        let (t1, t2) = tangent_basis(at.ground_normal);
        let downhill = self.azimuth.cos() * t1 + self.azimuth.sin() * t2;
        let g = at.gravity.length();
        let tilted = g * (self.angle.sin() * downhill - self.angle.cos() * at.ground_normal);
        let extra = tilted - at.gravity;
        for &s in &bound.shapes {
            at.world.shapes.range(s).for_each(|i| accel[i] += extra);
        }
    }
}

/// Two unit vectors spanning the plane with normal `n`; (x, y) for a horizontal table.
pub fn tangent_basis(n: Vec3) -> (Vec3, Vec3) {
    let seed = if n.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
    let t1 = (seed - seed.dot(n) * n).normalize();
    (t1, n.cross(t1))
}

#[cfg(test)]
mod tests {
    use super::super::tests::one_box;
    use super::super::{EffectModel, ShapeState};
    use super::*;

    #[test]
    fn table_tilt_adds_the_downhill_component_of_gravity() {
        let w = one_box();
        let tilt = TableTilt {
            angle: 0.1,
            azimuth: std::f32::consts::FRAC_PI_2,
        };
        let model = EffectModel::bind(&[tilt.into()], &w).unwrap();
        let n = w.particles.len();
        let mut accel = vec![Vec3::ZERO; n];
        let state = ShapeState {
            mass: &[1.0],
            velocity: &[Vec3::ZERO],
        };
        let g = Vec3::new(0.0, 0.0, -9.81);
        model.add_accelerations(&w, &w.particles.inv_mass, &state, g, Vec3::Z, &mut accel);
        let total = g + accel[0];
        assert!(
            (total.y - 9.81 * 0.1f32.sin()).abs() < 1e-5,
            "downhill along +y: {total}"
        );
        assert!(
            (total.length() - 9.81).abs() < 1e-4,
            "tilt only turns gravity"
        );
    }
}
