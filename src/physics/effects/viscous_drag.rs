//! Viscous drag: air or fluid resistance, a dragging cable. Total force `-coefficient * v_com` on
//! the object (N s/m), shared by its particles in proportion to their mass.

use super::{Bound, Family, FitSetting, Forces, Term};
use crate::physics::Effect;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViscousDrag {
    /// None: every dynamic object.
    #[serde(default)]
    pub object: Option<String>,
    pub coefficient: f32,
}

impl Term for ViscousDrag {
    fn object(&self) -> Option<&str> {
        self.object.as_deref()
    }

    fn parameters(&self) -> Vec<(&'static str, f32)> {
        vec![("coefficient", self.coefficient)]
    }

    fn parameter_mut(&mut self, name: &str) -> Option<&mut f32> {
        (name == "coefficient").then_some(&mut self.coefficient)
    }

    fn check(&self) -> Option<&'static str> {
        (self.coefficient < 0.0).then_some("coefficient must be >= 0")
    }

    fn accelerate(&self, at: &Forces, bound: &Bound, accel: &mut [glam::Vec3]) {
        for &s in &bound.shapes {
            let a = -self.coefficient / at.shape.mass[s as usize] * at.shape.velocity[s as usize];
            at.world.shapes.range(s).for_each(|i| accel[i] += a);
        }
    }
}

/// The drag coefficient of one object, from 0.03 to 30 times its mass per second.
#[derive(Debug)]
pub struct DragFamily;

impl Family for DragFamily {
    fn id(&self) -> &'static str {
        "viscous_drag"
    }

    fn parameter(&self) -> (&'static str, &'static str) {
        ("coefficient", "N s/m")
    }

    fn complexity(&self) -> usize {
        1
    }

    fn range(&self, s: &FitSetting) -> Option<(f32, f32, bool)> {
        Some((0.03 * s.mass, 30.0 * s.mass, true))
    }

    fn effect(&self, s: &FitSetting, value: f32) -> Option<Effect> {
        Some(
            ViscousDrag {
                object: Some(s.object.clone()),
                coefficient: value,
            }
            .into(),
        )
    }

    fn regression(&self) -> Option<&'static str> {
        Some("viscous_drag")
    }
}
